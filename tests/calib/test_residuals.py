"""The fit residuals of an estimate: against the motion pairs themselves and against the simulator's noise."""

import math

import pytest
import torch
from calib_helpers import lds_rig, no_gating

from ocalib.calib.drivers.online import OnlineCalibrator
from ocalib.geometry import rotation_angle
from ocalib.geometry.pose import invert_pose


def stream(poses, **options):
    cal = OnlineCalibrator(2, **options)
    for t in range(len(poses)):
        out = cal(poses[t])
    return out


def test_residuals_equal_the_pairs_own(generator):
    """Frame-0 pairs, one direction, every row weight 1: the residuals recomputed pair by pair from the poses
    and the final estimate (translation exactly; rotation to first order in the angle)."""
    poses, _, _ = lds_rig(generator, frames=60, noise=0.01)
    out = stream(poses, **no_gating(motion="first", symmetric=False, refine=False))
    motion = invert_pose(poses[:1]) @ poses[1:]  # (T-1, 2, 4, 4): frame 0 to t
    dR, dT, s = out.rotation[0, 0], out.translation[0, 0], out.scale[0, 0]
    R0, t0, R1, t1 = motion[:, 0, :3, :3], motion[:, 0, :3, 3], motion[:, 1, :3, :3], motion[:, 1, :3, 3]
    mismatch = rotation_angle((dR.T @ R0 @ dR).mT @ R1)  # camera 0's motion in camera k's frame vs camera k's
    rows = (torch.eye(3, dtype=dR.dtype) - R0) @ dT + s * (dR @ t1.unsqueeze(-1)).squeeze(-1) - t0
    relative = (rows.square().sum() / t0.square().sum()).sqrt()
    res = out.residuals
    assert float(res["rotation_deg"][0, 0]) == pytest.approx(
        math.degrees(float(mismatch.square().mean().sqrt())), rel=1e-3
    )
    assert float(res["translation_relative"][0, 0]) == pytest.approx(float(relative), rel=1e-9)


@pytest.mark.parametrize("sigma", [0.0, 0.002, 0.01])
def test_rotation_residual_follows_the_noise(generator, sigma):
    """Independent noise sigma (rad, per axis) on each pose: a pair's two motions differ by the error of four poses,
    about 2 sqrt(3) sigma in angle; noise-free data leave nothing."""
    poses, _, _ = lds_rig(generator, frames=128, noise=sigma)
    rotation = float(stream(poses).residuals["rotation_deg"][0, 0])
    if sigma == 0:
        assert rotation < 1e-6
    else:
        assert rotation == pytest.approx(math.degrees(2 * math.sqrt(3) * sigma), rel=0.2)
