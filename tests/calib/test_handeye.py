import torch
from calib_helpers import lds_rig

from ocalib.calib.handeye import (
    normal_equations,
    rotation_block,
    translation_features,
    translation_quadratic,
    translation_rows,
)
from ocalib.geometry import invert_pose, rotation_matrix_to_quaternion


def test_true_extrinsic_solves_both_equations(generator):
    poses, X, s = lds_rig(generator, frames=20)
    motion = invert_pose(poses[:-1]) @ poses[1:]  # consecutive motions (19, 2, 4, 4)
    q = rotation_matrix_to_quaternion(motion[..., :3, :3])
    dq = rotation_matrix_to_quaternion(X[0, :3, :3])
    for sign in (1.0, -1.0):  # either sign of camera 1's quaternion must give the same block
        A = rotation_block(q[:, 0], sign * q[:, 1])
        assert (A @ dq).abs().max() < 1e-12
        assert (A @ (-dq)).abs().max() < 1e-12
    B, b = translation_rows(motion[:, 0, :3, :3], motion[:, 0, :3, 3], motion[:, 1, :3, 3], X[0, :3, :3])
    x = torch.cat([X[0, :3, 3], s])
    torch.testing.assert_close(B @ x, b, atol=1e-12, rtol=0)


def test_normal_equations_equal_explicit_rows(generator):
    poses, X, _ = lds_rig(generator, frames=30, noise=0.05)
    motion = invert_pose(poses[:-1]) @ poses[1:]
    R0, t0, t1 = motion[:, 0, :3, :3], motion[:, 0, :3, 3], motion[:, 1, :3, 3]
    w = torch.rand(len(motion), generator=generator, dtype=torch.float64)
    z = translation_features(R0, t0, t1)
    Z = (z * w[:, None]).T @ z
    dR = X[0, :3, :3]
    H, g, tt = normal_equations(translation_quadratic(Z), dR[None])
    B, b = translation_rows(R0, t0, t1, dR)
    Bw, bw = B * w.sqrt()[:, None, None], b * w.sqrt()[:, None]
    Bf, bf = Bw.reshape(-1, 4), bw.reshape(-1)
    torch.testing.assert_close(H, Bf.T @ Bf, atol=1e-10, rtol=1e-12)
    torch.testing.assert_close(g, Bf.T @ bf, atol=1e-10, rtol=1e-12)
    torch.testing.assert_close(tt, bf @ bf, atol=1e-10, rtol=1e-12)
