import math

import pytest
import torch
from calib_helpers import lds_rig

from ocalib.calib.drivers.online import OnlineCalibrator
from ocalib.calib.drivers.sequence import calibrate_sequence
from ocalib.geometry import make_pose
from ocalib.geometry.quaternion import so3_exp

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


@pytest.mark.parametrize(
    "options", [{}, {"motion": "first"}, {"forgetting": 0.9}, {"refine": False}, {"scale_fit": "regression"}]
)
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
