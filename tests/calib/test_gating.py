"""The gates of the hand-eye rows: their compiled twins, and the screw gate over a whole sequence."""

import math

import numpy as np
import torch
from calib_helpers import random_orthonormal, random_poses, random_rotations

from ocalib.calib.stages import gating_kernel
from ocalib.calib.stages.gating import affine_scan, check_poses, rotation_weights, screw_gate, screw_gate_sequence
from ocalib.calib.stages.handeye import rotation_blocks
from ocalib.calib.stages.rotation import RotationSystem, rotation_solution
from ocalib.geometry import quaternion_to_rotation_matrix, rotation_matrix_to_quaternion
from ocalib.geometry.quaternion import so3_exp


def test_check_poses_twin(generator):
    poses = random_poses(generator, 6, 3)
    poses[0, 1, 0, 0] = math.nan
    poses[1, 2, 2, 3] = math.inf
    poses[2, 0, :3, :3] *= 1.01  # not orthonormal
    poses[3, 1, :3, :3] *= -1  # a reflection
    poses[4, 2, :3, :3] += 1e-4  # within the tolerance
    want, want_valid = check_poses(poses, 1e-3)
    assert want_valid.sum() == 18 - 4
    for b in range(len(poses)):
        got, valid = np.empty((3, 4, 4)), np.empty(3, dtype=np.bool_)
        gating_kernel.check_poses(poses[b].numpy(), 1e-3, got, valid)
        np.testing.assert_array_equal(valid, want_valid[b].numpy())
        np.testing.assert_array_equal(got, want[b].numpy())


def test_screw_gate_twin(generator):
    B, C, P = 8, 3, 5
    angle = torch.rand(B, 1, P, generator=generator, dtype=torch.float64).expand(B, C, P).clone()
    angle[:, 1:] += 0.01 * torch.randn(B, C - 1, P, generator=generator, dtype=torch.float64)
    angle[:, 1:, 0] += 0.5  # an outlier: clipped, then gated once the gate is open
    valid = torch.rand(B, C - 1, P, generator=generator) < 0.8
    scale = 0.01 * torch.rand(B, C - 1, generator=generator, dtype=torch.float64)
    count = torch.tensor([0.0, 5.0, 10.0, 200.0, 999.0, 1000.0, 12.0, 40.0], dtype=torch.float64)[:, None].expand(B, 2)
    want_ok, want_scale, want_count = screw_gate(angle, valid, scale, count, math.radians(1), 4.0)
    assert want_ok.any() and (valid & ~want_ok).any()
    for b in range(B):
        ok, s, n = np.empty((C - 1, P), dtype=np.bool_), scale[b].numpy().copy(), count[b].numpy().copy()
        gating_kernel.screw_gate(angle[b].numpy(), valid[b].numpy(), s, n, math.radians(1), 4.0, ok)
        np.testing.assert_array_equal(ok, want_ok[b].numpy())
        np.testing.assert_allclose(s, want_scale[b].numpy(), rtol=1e-12, atol=1e-15)
        np.testing.assert_array_equal(n, want_count[b].numpy())


def test_rotation_weights_twin(generator):
    """Pairs gated, not moving, within and beyond the robust threshold, under established and unknown estimates."""
    B, P = 6, 7
    V = random_orthonormal(generator, B, 1)
    dR = quaternion_to_rotation_matrix(rotation_solution(V))[:, :, None]  # the estimate's rotation (B, 1, 1, 3, 3)
    R0 = random_rotations(generator, B, 1, P)
    off = torch.tensor([0.0, 0.01, 0.02, 0.3, 0.5, 0.0, 0.0], dtype=torch.float64)[:, None]  # 0.6 to 30 degrees
    Rk = dR.mT @ R0 @ dR @ so3_exp(off * torch.randn(B, 1, P, 3, generator=generator, dtype=torch.float64))
    Rk[:, :, -1], R0[:, :, -1] = torch.eye(3, dtype=torch.float64), torch.eye(3, dtype=torch.float64)  # not moving
    q = rotation_matrix_to_quaternion(torch.cat([R0, Rk], 1))  # (B, C, P, 4)
    angle = 2 * torch.atan2(q[..., 1:].norm(dim=-1), q[..., 0].abs())
    A = rotation_blocks(q)
    ok = torch.rand(B, 1, P, generator=generator) < 0.8
    S2 = torch.tensor([4.0, 3.0, 2.0, 1e-4], dtype=torch.float64).expand(B, 1, 4).clone()
    S2[::2, :, 2] = 1e-4  # rotation not observable: every weight 1
    estimate = RotationSystem(S2, V, torch.full((B, 1), 50.0, dtype=torch.float64))
    want = rotation_weights(ok, angle, A, estimate, math.radians(0.05), math.radians(5.0))
    assert ((want > 0) & (want < 1)).any() and ((want == 1) & (S2[..., 2:3] > 1)).any() and (want == 0).any()
    for b in range(B):
        weight = np.empty(P)
        est = RotationSystem(S2[b, 0].numpy(), V[b, 0].numpy(), 50.0)
        gating_kernel.rotation_weights(ok[b, 0].numpy(), angle[b, 0].numpy(), angle[b, 1].numpy(), A[b, 0].numpy(), est,
                                       math.radians(0.05), math.radians(5.0), weight)  # fmt: skip
        np.testing.assert_allclose(weight, want[b, 0].numpy(), rtol=1e-10, atol=0)


def test_affine_scan_equals_the_recurrence(generator):
    a = torch.rand(37, 3, generator=generator, dtype=torch.float64)
    b = torch.randn(37, 3, generator=generator, dtype=torch.float64)
    s, expected = torch.ones(3, dtype=torch.float64), []
    for t in range(37):
        s = a[t] * s + b[t]
        expected.append(s)
    torch.testing.assert_close(affine_scan(a, b, torch.ones(3, dtype=torch.float64)), torch.stack(expected))


def test_screw_gate_sequence_equals_frame_by_frame(generator):
    L, P = 200, 4
    angle = torch.rand(L, 2, 3, P, generator=generator, dtype=torch.float64)  # 2 rigs of 3 cameras
    angle[:, :, 1:] = angle[:, :, :1] + torch.rand(L, 2, 2, P, generator=generator, dtype=torch.float64).mul(0.01)
    angle[:, :, 1:][torch.rand(L, 2, 2, P, generator=generator) < 0.1] += 0.5  # outliers: clipped, then gated
    valid = torch.rand(L, 2, 2, P, generator=generator) < 0.9
    scale, count = torch.zeros(2, 2, dtype=torch.float64), torch.zeros(2, 2, dtype=torch.float64)
    ok = []
    for t in range(L):
        ok_t, scale, count = screw_gate(angle[t], valid[t], scale, count, math.radians(1), 4.0)
        ok.append(ok_t)
    zero = torch.zeros(2, 2, dtype=torch.float64)
    got, got_scale, got_count = screw_gate_sequence(angle, valid, zero, zero, math.radians(1), 4.0)
    assert torch.equal(got, torch.stack(ok)) and (~got & valid).any()
    torch.testing.assert_close(got_scale, scale, atol=1e-14, rtol=0)
    torch.testing.assert_close(got_count, count)
