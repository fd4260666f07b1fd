import numpy as np
import pytest
import torch
from calib_helpers import lds_rig, random_moment, random_poses, random_rotations

from ocalib.calib.stages import handeye_kernel
from ocalib.calib.stages.handeye import (
    TranslationMoment,
    normal_equations,
    rotation_block,
    rotation_blocks,
    row_statistics,
    translation_features,
    translation_quadratic,
    translation_rows,
    update_translation_moment,
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
    Z = (row_statistics(translation_features(R0, t0, t1)) * w[:, None]).sum(0)
    dR = X[0, :3, :3]
    H, g, tt = normal_equations(translation_quadratic(Z), dR[None])
    B, b = translation_rows(R0, t0, t1, dR)
    Bw, bw = B * w.sqrt()[:, None, None], b * w.sqrt()[:, None]
    Bf, bf = Bw.reshape(-1, 4), bw.reshape(-1)
    torch.testing.assert_close(H, Bf.T @ Bf, atol=1e-10, rtol=1e-12)
    torch.testing.assert_close(g, Bf.T @ bf, atol=1e-10, rtol=1e-12)
    torch.testing.assert_close(tt, bf @ bf, atol=1e-10, rtol=1e-12)


def test_translation_quadratic_equals_explicit_residual(generator):
    """The 58 statistics give the rows' residual for any ``y = (dT, vec(s dR))``, not only at rotations."""
    z = torch.randn(9, 15, generator=generator, dtype=torch.float64)
    P, p, c = translation_quadratic(row_statistics(z).sum(0))
    for y in torch.randn(5, 12, generator=generator, dtype=torch.float64):
        E, t1, t0 = z[:, :9].unflatten(-1, (3, 3)), z[:, 9:12], z[:, 12:]
        residual = E @ y[:3] + t1 @ y[3:].view(3, 3).T - t0  # rows r: E_r . dT + m_r . t1 - t0[r]
        torch.testing.assert_close(y @ P @ y - 2 * p @ y + c, residual.square().sum(), rtol=1e-12, atol=1e-12)


def test_rotation_blocks_twin(generator):
    q = rotation_matrix_to_quaternion(random_rotations(generator, 3, 2, 6))  # (B, C, P, 4), w >= 0
    want = rotation_blocks(q)[:, 0]
    for b in range(len(q)):
        got = np.empty((6, 4, 4))
        handeye_kernel.rotation_blocks(q[b, 0].numpy(), q[b, 1].numpy(), got)
        np.testing.assert_array_equal(got, want[b].numpy())


@pytest.mark.parametrize("symmetric", [True, False])
@pytest.mark.parametrize("forgetting", [1.0, 0.9])
def test_update_translation_moment_twin(generator, symmetric, forgetting):
    B, C, P = 4, 2, 5
    motion = random_poses(generator, B, C, P, scale=3.0)
    ok = torch.rand(B, C - 1, P, generator=generator) < 0.7
    moment = TranslationMoment(
        random_moment(generator, B, 1, P),
        10 * torch.rand(B, 1, P, generator=generator, dtype=torch.float64),
        random_moment(generator, B, 1, P),
    )
    want = update_translation_moment(moment, motion, ok, forgetting, symmetric)
    for b in range(B):
        got = TranslationMoment(*(x[b, 0].numpy().copy() for x in moment))
        handeye_kernel.update_translation_moment(got, motion[b, 0].numpy(), motion[b, 1].numpy(), ok[b, 0].numpy(),
                                                 forgetting, symmetric, np.empty((2, 15)))  # fmt: skip
        np.testing.assert_allclose(got.Z, want.Z[b, 0].numpy(), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(got.Z_reverse, want.Z_reverse[b, 0].numpy(), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(got.translation_rows, want.translation_rows[b, 0].numpy(), rtol=1e-14)


def test_translation_quadratic_and_normal_equations_twins(generator):
    Z, maps = random_moment(generator, 3), random_rotations(generator, 3, 3)  # maps: any 3x3 matrices
    for b in range(3):
        P, p = np.empty((12, 12)), np.empty(12)
        c = handeye_kernel.translation_quadratic(Z[b].numpy(), P, p)
        want = translation_quadratic(Z[b])
        for got, expected in zip((P, p, c), want):
            np.testing.assert_array_equal(got, expected.numpy())
        for m in (1, 3):
            H, g = np.empty((6, 6)), np.empty(6)
            handeye_kernel.normal_equations((P, p, c), maps[b].numpy(), m, H, g)
            want_H, want_g, _ = normal_equations(want, maps[b, :m])
            np.testing.assert_allclose(H[: 3 + m, : 3 + m], want_H.numpy(), rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(g[: 3 + m], want_g.numpy(), rtol=1e-12, atol=1e-12)
