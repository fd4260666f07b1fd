import math

import pytest
import torch
from calib_helpers import lds_rig

from ocalib.calib.gating import affine_scan, screw_gate, screw_gate_sequence
from ocalib.calib.online import OnlineCalibrator
from ocalib.calib.sequence import calibrate_sequence
from ocalib.geometry import make_pose
from ocalib.sim.trajectory import so3_exp

FIELDS = ("quaternion", "translation", "scale", "rotation_singular_values")


def stream(poses, **options):
    """Per-frame outputs of the streaming head on poses (T, [B,] C, 4, 4), stacked on a leading T axis."""
    batch = poses.dim() == 5
    cal = OnlineCalibrator(poses.shape[-3], batch_size=poses.shape[1] if batch else 1, **options)
    outs = [cal(poses[t]) for t in range(len(poses))]
    names = FIELDS + ("frames_used", "frames_rejected", "planar_motion", "rotation_observable")
    return {n: torch.stack([getattr(o, n) if batch else getattr(o, n)[0] for o in outs]) for n in names}


def assert_same(seq, ref, start=3):
    for name in ref:
        got, want = getattr(seq, name)[start:], ref[name][start:]
        if got.dtype == torch.float64:
            torch.testing.assert_close(got, want, atol=1e-8, rtol=0, msg=name)
        else:
            assert torch.equal(got, want), name


@pytest.mark.parametrize("options", [{}, {"motion": "first"}, {"forgetting": 0.9}, {"refine": False}])
def test_sequence_equals_stream_every_frame(generator, options):
    poses, _, _ = lds_rig(generator, frames=90, cameras=3, noise=0.01)
    with torch.no_grad():
        assert_same(calibrate_sequence(poses, chunk=32, **options), stream(poses, **options))


def test_sequence_equals_stream_with_outliers_and_bad_poses(generator):
    """The screw gate and the robust weights (both recursive) and invalid poses, over several chunks."""
    poses, _, _ = lds_rig(generator, frames=120, noise=0.003)
    poses = torch.stack([poses, lds_rig(generator, frames=120, noise=0.003)[0]], 1)  # two rigs (T, B, C, 4, 4)
    jump = make_pose(so3_exp(torch.tensor([0.35, 0.0, 0.0], dtype=torch.float64)), torch.zeros(3, dtype=torch.float64))
    for t in range(30, 120, 7):
        poses[t, 0, 1] = poses[t, 0, 1] @ jump  # camera 1 of rig 0 jumps by 20 degrees for a frame
    poses[50, 1, 0, 0, 0] = math.nan
    poses[70, 1, 1, :3, :3] *= 1.1
    options = {"motion": (0, 1, 2, 4)}
    with torch.no_grad():
        seq, ref = calibrate_sequence(poses, chunk=16, **options), stream(poses, **options)
    assert_same(seq, ref)
    assert ref["frames_rejected"][-1, 1].item() == 2 and ref["frames_rejected"][-1, 0].item() > 0


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
