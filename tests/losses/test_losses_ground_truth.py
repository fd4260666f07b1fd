"""On the renderer's ground-truth depth and poses the photometric loss is near zero (much larger with a wrong
pose) and the depths of target and source agree (geometry consistency)."""

import pytest
import torch

from ocalib.geometry.pose import invert_pose, make_pose
from ocalib.losses import depth_inconsistency, inverse_warp, photometric_error, self_supervised_loss
from ocalib.losses.gauge import scale_gauge
from ocalib.models import MAX_DEPTH, MIN_DEPTH, disp_to_depth
from ocalib.synth import preset, render_rig

ROTATED = make_pose(
    torch.linalg.matrix_exp(torch.tensor([[0.0, -0.03, 0], [0.03, 0, 0], [0, 0, 0]]))[None], torch.zeros(1, 3)
)  # 1.7 degrees about the optical axis


@pytest.fixture(scope="module")
def snippet():
    """A 3-frame snippet of camera 0 (target = middle frame) at 48x160: images, depth, K, T_source_target."""
    torch.set_num_threads(1)
    seq = render_rig(preset("handheld").with_overrides(frames=3, height=48, width=160))
    K = torch.from_numpy(seq.rig.cameras[0].K).float()[None]
    poses = seq.poses[0]  # (3, 4, 4) camera-to-world
    order = [1, 0, 2]
    images = seq.images[0, order][None]  # (1, 3, 3, H, W)
    depth = seq.depth[0, order][:, None][None]  # (1, 3, 1, H, W), 0 = sky
    T = torch.stack([invert_pose(poses[s]) @ poses[1] for s in order[1:]]).float()[None]  # (1, 2, 4, 4)
    return images, depth, K, T


def gt_disparity(depth):
    """Invert disp_to_depth; sky (0) goes to the farthest depth."""
    d = torch.where(depth > 0, depth, torch.full_like(depth, MAX_DEPTH)).clamp(MIN_DEPTH, MAX_DEPTH)
    lo, hi = 1 / MAX_DEPTH, 1 / MIN_DEPTH
    return (1 / d - lo) / (hi - lo)


def test_ground_truth_warp_is_photometrically_exact_and_wrong_pose_is_not(snippet):
    images, depth, K, T = snippet
    surface = depth[:, 0] > 0
    errors = {}
    wrong = ROTATED @ T[:, 0]
    for name, pose in [("true", T[:, 0]), ("wrong", wrong)]:
        warp = inverse_warp(images[:, 1], depth[:, 0], pose, K)
        keep = surface & (warp.mask > 0)
        errors[name] = photometric_error(warp.image, images[:, 0])[keep].mean()
    assert errors["true"] < 0.06  # rendering differences only (identity: ~0.2)
    assert errors["wrong"] > 2 * errors["true"]


def test_self_supervised_loss_is_small_at_ground_truth(snippet):
    images, depth, K, T = snippet
    disp = [gt_disparity(depth[:, 0])]
    truth = self_supervised_loss(images, K, disp, T, depth[:, 1:], automask=False, smoothness=0, geometry=0.5)
    wrong = self_supervised_loss(images, K, disp, ROTATED @ T, depth[:, 1:], automask=False, smoothness=0, geometry=0.5)
    assert truth.terms["photometric"] < 0.06
    assert wrong.terms["photometric"] > 2.5 * truth.terms["photometric"]
    gauge = truth.terms["gauge"]  # the same depth: the same scale gauge
    assert wrong.total - gauge > 2.5 * (truth.total - gauge)


def test_scale_gauge_holds_the_depth_scale_in_the_loss(snippet):
    images, depth, K, T = snippet
    for scale in (0.1, 30.0):  # the truth in tenths of metres (within the band) and a drifted network scale
        disp = gt_disparity(depth[:, 0] * scale)
        out = self_supervised_loss(images, K, [disp], T, automask=False, smoothness=0)
        gauge = scale_gauge(disp_to_depth(disp, MIN_DEPTH, MAX_DEPTH), MIN_DEPTH, MAX_DEPTH)
        assert (gauge > 0) == (scale > 1.0)
        torch.testing.assert_close(out.terms["gauge"], gauge)
        torch.testing.assert_close(out.total, out.terms["photometric"] + gauge)


def test_ground_truth_depths_are_geometrically_consistent(snippet):
    images, depth, K, T = snippet
    warp = inverse_warp(images[:, 2], depth[:, 0], T[:, 1], K, depth[:, 2])
    keep = (depth[:, 0] > 0) & (warp.mask > 0) & (warp.source_depth > 0)
    diff = depth_inconsistency(warp.depth, warp.source_depth)[keep]
    assert keep.float().mean() > 0.3
    assert diff.median() < 0.01
