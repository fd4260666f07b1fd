"""Direct photometric alignment against the renderer's ground truth: from a perturbed motion and the true depth it
returns the true motion; a correction beyond its limit is refused and the input kept."""

import math

import pytest
import torch

from ocalib.frontend.align import align_motion, photometric_cost
from ocalib.geometry.pose import invert_pose, make_pose
from ocalib.geometry.quaternion import rotation_angle
from ocalib.synth import preset, render_rig

# 1 degree about a tilted axis and 3 cm: a typical error of the pose network on one frame (README, issue 4)
AXIS = torch.tensor([0.3, 1.0, 0.2], dtype=torch.float64)
PERTURBATION = make_pose(torch.linalg.matrix_exp(torch.cross(torch.eye(3, dtype=torch.float64),
                                                             (math.radians(1) * AXIS / AXIS.norm()).expand(3, 3),
                                                             dim=-1))[None], torch.tensor([[0.03, -0.01, 0.02]]))


def rotation_error_deg(A, B):
    return torch.rad2deg(rotation_angle(A[..., :3, :3].mT @ B[..., :3, :3]))


@pytest.fixture(scope="module")
def pair():
    """Frames 0 (target) and 1 (source) of camera 0 of a handheld rig at 128x416 (at 64x208 the true motion is
    found to 0.06 deg and 2 cm of an 11 cm step): images, true depth (sky far), K and the true T_source_target."""
    torch.set_num_threads(1)
    seq = render_rig(preset("handheld").with_overrides(frames=2, height=128, width=416))
    target, source = seq.images[0, 0][None], seq.images[0, 1][None]
    depth = seq.depth[0, 0][None, None]
    depth = torch.where(depth > 0, depth, torch.full_like(depth, 100.0))
    K = torch.from_numpy(seq.rig.cameras[0].K).float()[None]
    T = (invert_pose(seq.poses[0, 1]) @ seq.poses[0, 0])[None].double()
    return target, source, depth, K, T


def test_align_recovers_the_true_motion(pair, device):
    target, source, depth, K, T = (x.to(device) for x in pair)
    start = PERTURBATION.to(device) @ T
    assert float(rotation_error_deg(start, T)) == pytest.approx(1.0, abs=1e-6)
    aligned, accepted = align_motion(target, source, depth, K, start)
    assert bool(accepted[0]) and aligned.dtype == torch.float64 and aligned.device.type == device.type
    assert float(rotation_error_deg(aligned, T)) < 0.05
    assert float((aligned[0, :3, 3] - T[0, :3, 3]).norm()) < 0.25 * float((start[0, :3, 3] - T[0, :3, 3]).norm())
    costs = [float(photometric_cost(target, source, depth, K, M.float())) for M in (start, aligned, T)]
    assert costs[1] < costs[0] and costs[1] <= costs[2] + 1e-3


def test_align_keeps_the_input_beyond_its_limit(pair):
    target, source, depth, K, T = pair
    start = PERTURBATION @ T
    aligned, accepted = align_motion(target, source, depth, K, start, max_rotation_deg=0.1)
    assert not bool(accepted[0])
    assert torch.equal(aligned, start)


def test_align_solves_a_batch_as_separate_problems(pair):
    target, source, depth, K, T = pair
    start = torch.cat([PERTURBATION @ T, T])
    aligned, accepted = align_motion(target.expand(2, -1, -1, -1), source.expand(2, -1, -1, -1),
                                     depth.expand(2, -1, -1, -1), K.expand(2, -1, -1), start)
    single, _ = align_motion(target, source, depth, K, start[:1])
    assert torch.allclose(aligned[:1], single, atol=1e-6)
    assert (rotation_error_deg(aligned, T) < 0.05).all()


def test_align_refuses_mismatched_shapes(pair):
    target, source, depth, K, T = pair
    with pytest.raises(ValueError, match="depth"):
        align_motion(target, source, depth[..., :-1], K, T)
    with pytest.raises(ValueError, match="K"):
        align_motion(target, source, depth, K[0], T)
    with pytest.raises(ValueError, match="T_source_target"):
        align_motion(target, source, depth, K, T.expand(2, 4, 4))


def test_align_refuses_a_depth_without_valid_pixels(pair):
    """NaN or zero depth leaves no pixel to compare: the input motion is kept, flagged, finite."""
    target, source, depth, K, T = pair
    for bad in (depth * float("nan"), depth * 0):
        aligned, accepted = align_motion(target, source, bad, K, T)
        assert not bool(accepted[0]) and torch.equal(aligned, T)
