"""Direct photometric alignment against the renderer's ground truth: from a perturbed motion and the true depth it
returns the true motion; a correction beyond its limit is refused and the input kept; a start outside the basin is
rescued by a prior inside it (the stream aligner's previous motion); with the rotation held, the translation is
found on a depth whose error grows across the image (a tilt), where the 6-DoF alignment is pulled off; the
analytic Jacobian against central differences of kornia's warp."""

import math

import kornia
import pytest
import torch
from kornia.geometry.depth import depth_to_3d_v2

from ocalib.frontend.align import (
    StreamAligner,
    _jacobian,
    align_motion,
    align_translation,
    image_gradient,
    photometric_cost,
)
from ocalib.geometry.pose import invert_pose, make_pose
from ocalib.geometry.quaternion import rotation_angle
from ocalib.losses import inverse_warp
from ocalib.models.pose import motion_to_pose
from ocalib.synth import preset, render_rig

# 1 degree about a tilted axis and 3 cm: a typical error of the pose network on one frame (docs/results-egomotion.md)
AXIS = torch.tensor([0.3, 1.0, 0.2], dtype=torch.float64)
PERTURBATION = make_pose(
    torch.linalg.matrix_exp(
        torch.cross(torch.eye(3, dtype=torch.float64), (math.radians(1) * AXIS / AXIS.norm()).expand(3, 3), dim=-1)
    )[None],
    torch.tensor([[0.03, -0.01, 0.02]]),
)

YAW_8_DEG = make_pose(
    torch.linalg.matrix_exp(
        torch.tensor([[[0.0, 0, 1], [0, 0, 0], [-1, 0, 0]]], dtype=torch.float64) * math.radians(8)
    ),
    torch.zeros(1, 3, dtype=torch.float64),
)  # 8 deg about the camera's y axis: outside the basin


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


def test_align_runs_in_float32_under_mixed_precision(pair, device):
    """Training with ``precision: bf16-mixed`` (configs/train/gpu.yaml) calls the alignment inside autocast: the
    result is the float32 one (before, linalg.solve met a bfloat16 gradient and raised)."""
    target, source, depth, K, T = (x.to(device) for x in pair)
    start = PERTURBATION.to(device) @ T
    expected, _ = align_motion(target, source, depth, K, start)
    with torch.autocast(device.type, dtype=torch.bfloat16):
        aligned, accepted = align_motion(target, source, depth, K, start)
        held, _ = align_translation(target, source, depth, K, start)
    assert bool(accepted[0]) and torch.allclose(aligned, expected, atol=1e-5)
    assert torch.isfinite(held).all()


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_image_gradient_is_kornias_sobel(device, dtype):
    image = torch.rand(2, 3, 7, 9, dtype=dtype, device=device)
    expected = kornia.filters.spatial_gradient(image, normalized=True).transpose(1, 2).flatten(1, 2)
    assert torch.allclose(image_gradient(image), expected, atol=1e-6)


def test_align_does_not_read_the_host(pair, device):
    """No host round-trip inside the alignment (CUDA: torch raises on any synchronising call in this mode;
    measured on an H100: none left in the aligned graph but the head's ``linalg.eigh``)."""
    if device.type != "cuda":
        pytest.skip("host reads are a CUDA matter")
    target, source, depth, K, T = (x.to(device) for x in pair)
    start = PERTURBATION.to(device) @ T
    torch.cuda.synchronize()
    torch.cuda.set_sync_debug_mode("error")
    try:
        aligned, _ = align_motion(target, source, depth, K, start, prior=T)
        held, _ = align_translation(target, source, depth, K, start)
    finally:
        torch.cuda.set_sync_debug_mode(0)
    assert float(rotation_error_deg(aligned, T)) < 0.05 and torch.isfinite(held).all()


def test_align_keeps_the_input_beyond_its_limit(pair):
    target, source, depth, K, T = pair
    start = PERTURBATION @ T
    aligned, accepted = align_motion(target, source, depth, K, start, max_rotation_deg=0.1)
    assert not bool(accepted[0])
    assert torch.equal(aligned, start)


def test_align_solves_a_batch_as_separate_problems(pair):
    target, source, depth, K, T = pair
    start = torch.cat([PERTURBATION @ T, T])
    aligned, accepted = align_motion(
        target.expand(2, -1, -1, -1),
        source.expand(2, -1, -1, -1),
        depth.expand(2, -1, -1, -1),
        K.expand(2, -1, -1),
        start,
    )
    single, _ = align_motion(target, source, depth, K, start[:1])
    assert torch.allclose(aligned[:1], single, atol=1e-6)
    assert (rotation_error_deg(aligned, T) < 0.05).all()


def test_a_prior_inside_the_basin_rescues_a_start_outside_it(pair):
    """From 8 deg off in yaw Gauss-Newton stops far from the truth; with a close prior beside it, the better of the
    two is kept (accepted: it beats the input motion); a prior that is the start itself changes nothing."""
    target, source, depth, K, T = pair
    far = YAW_8_DEG @ T
    alone, _ = align_motion(target, source, depth, K, far, max_rotation_deg=20)
    assert float(rotation_error_deg(alone, T)) > 2
    rescued, accepted = align_motion(target, source, depth, K, far, prior=PERTURBATION @ T, max_rotation_deg=20)
    assert bool(accepted[0]) and float(rotation_error_deg(rescued, T)) < 0.05
    same, _ = align_motion(target, source, depth, K, far, prior=far, max_rotation_deg=20)
    torch.testing.assert_close(same, alone, rtol=0, atol=1e-5)


def test_stream_aligner_starts_each_problem_from_its_previous_motion(pair):
    """The previous call's refined motion is the next call's prior (constant velocity), held in a buffer;
    reset() forgets it (the identity again)."""
    target, source, depth, K, T = pair
    aligner = StreamAligner(1, max_rotation_deg=20)
    assert torch.equal(aligner.previous, torch.eye(4)[None]) and "previous" in aligner.state_dict()
    first, _ = aligner(target, source, depth, K, PERTURBATION @ T)
    assert float(rotation_error_deg(first, T)) < 0.05
    second, _ = aligner(target, source, depth, K, YAW_8_DEG @ T)
    assert float(rotation_error_deg(second, T)) < 0.05
    aligner.reset()
    assert torch.equal(aligner.previous, torch.eye(4)[None])


def test_a_non_finite_motion_does_not_poison_the_stream(pair):
    """A NaN network motion is returned flagged; stored as the next prior, it never wins over a finite start, so
    the next frame aligns as if it had no prior."""
    target, source, depth, K, T = pair
    aligner = StreamAligner(1)
    bad, accepted = aligner(target, source, depth, K, torch.full_like(T, math.nan))
    assert not bool(accepted[0]) and torch.isnan(bad).all()
    after, accepted = aligner(target, source, depth, K, PERTURBATION @ T)
    alone, _ = align_motion(target, source, depth, K, PERTURBATION @ T)
    # equal up to rounding: the stream solves its two starts in one batch (bitwise equal on this CPU; on a 16-core
    # host with torch 2.11 the batched products round differently)
    assert bool(accepted[0]) and torch.allclose(after, alone, atol=1e-6, rtol=0)


def direction_error_deg(A, B):
    return math.degrees(math.acos(min(1.0, float(torch.nn.functional.cosine_similarity(A[0, :3, 3], B[0, :3, 3], 0)))))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_align_translation_holds_the_rotation_and_undoes_a_depth_tilt(pair, device, dtype):
    """The depth is off by a factor that grows across the image, 1 + 0.15 x - 0.2 y (x, y normalised image
    coordinates: ~ +-15 % at the left and right edges), as the network's depth is on a sideways camera. With the
    true rotation held and the translation 3.7 cm off (a third of the step), the translation comes back to within
    0.5 deg of the true direction and 5 % of the start's error; the 6-DoF alignment on the same depth is pulled
    more than 1.5 deg off in direction."""
    target, source, depth, K, T = (x.to(device) for x in pair)
    ray = depth_to_3d_v2(depth[:, 0], K)
    tilted = depth * (1 + 0.15 * ray[..., 0] / ray[..., 2] - 0.2 * ray[..., 1] / ray[..., 2])[:, None]
    start = T.clone()
    start[0, :3, 3] += torch.tensor([0.03, -0.01, 0.02], dtype=T.dtype, device=device)
    aligned, accepted = align_translation(target, source, tilted, K, start.to(dtype))
    assert bool(accepted[0]) and aligned.dtype == dtype and aligned.device.type == device.type
    aligned = aligned.double()
    torch.testing.assert_close(aligned[:, :3, :3], T[:, :3, :3], rtol=0, atol=1e-6)
    assert direction_error_deg(aligned, T) < 0.5
    assert float((aligned[0, :3, 3] - T[0, :3, 3]).norm()) < 0.05 * float((start[0, :3, 3] - T[0, :3, 3]).norm())
    full, _ = align_motion(target, source, tilted, K, PERTURBATION.to(device) @ T)
    assert direction_error_deg(full, T) > 1.5


def test_align_refuses_mismatched_shapes(pair):
    target, source, depth, K, T = pair
    with pytest.raises(ValueError, match="depth"):
        align_motion(target, source, depth[..., :-1], K, T)
    with pytest.raises(ValueError, match="K"):
        align_motion(target, source, depth, K[0], T)
    with pytest.raises(ValueError, match="T_source_target"):
        align_motion(target, source, depth, K, T.expand(2, 4, 4))
    with pytest.raises(ValueError, match="prior"):
        align_motion(target, source, depth, K, T, prior=T[0])
    with pytest.raises(ValueError, match="depth"):
        align_translation(target, source, depth[..., :-1], K, T)


def test_align_refuses_a_depth_without_valid_pixels(pair):
    """NaN or zero depth leaves no pixel to compare: the input motion is kept, flagged, finite."""
    target, source, depth, K, T = pair
    for bad in (depth * float("nan"), depth * 0):
        aligned, accepted = align_motion(target, source, bad, K, T)
        assert not bool(accepted[0]) and torch.equal(aligned, T)
        assert torch.equal(align_translation(target, source, bad, K, T)[0], T)


@pytest.mark.parametrize("translation_only", [False, True])
def test_gauss_newton_jacobian_matches_finite_differences_of_the_kornia_warp(translation_only, device):
    """The analytic Jacobian of the alignment (:func:`ocalib.frontend.align._jacobian`) against central differences
    of the residual of :func:`ocalib.losses.inverse_warp` (kornia), on a smooth image (where the sampled Sobel
    gradient and the bilinear interpolant's slope agree): the left correction's rotation and translation, and with
    the rotation held, the translation and the inverse depth's tilt (a depth divided by 1 + tilt . ray)."""
    H, W, f64 = 48, 64, dict(dtype=torch.float64, device=device)
    v, u = torch.meshgrid(torch.arange(H, **f64), torch.arange(W, **f64), indexing="ij")
    source = (
        0.5
        + 0.2 * torch.sin(2 * math.pi * 0.75 * u / W + 0.3) * torch.cos(2 * math.pi * 0.6 * v / H)
        + 0.1 * torch.sin(2 * math.pi * (u + v) / 180)
    )[None, None]
    depth = (4 + 0.02 * v)[None, None]
    f, cx, cy = 50.0, 31.5, 23.5
    K = torch.tensor([[[f, 0, cx], [0, f, cy], [0, 0, 1]]], **f64)
    T = motion_to_pose(torch.tensor([[0.01, -0.03, 0.02, 0.10, -0.05, 0.20]], **f64))
    tilt = torch.tensor([[0.15, -0.10]], **f64)
    points = depth_to_3d_v2(depth[:, 0], K).reshape(1, -1, 3).transpose(1, 2)  # (1, 3, N)
    ray = points[:, :2] / points[:, 2:]

    def residual(x):  # x: the correction (6,), or (translation (3,), tilt (2,)) with the rotation held
        if translation_only:
            factor = 1 + (ray * (tilt + x[3:])[..., None]).sum(1)
            moved = T.clone()
            moved[:, :3, 3] += x[:3]
            return inverse_warp(source, depth / factor.view(1, 1, H, W), moved, K).image.flatten(2)
        return inverse_warp(source, depth, motion_to_pose(x[None]) @ T, K).image.flatten(2)

    h, n = 1e-5, 5 if translation_only else 6
    numeric = torch.stack([(residual(h * e) - residual(-h * e)) / (2 * h) for e in torch.eye(n, **f64)], 1)[:, :, 0]
    factor = (1 + (ray * tilt[..., None]).sum(1, keepdim=True)) if translation_only else torch.ones_like(ray[:, :1])
    X = T[:, :3, :3] @ (points / factor) + T[:, :3, 3:]
    iz = 1 / X[:, 2]
    a, b = X[:, 0] * iz, X[:, 1] * iz
    grid = torch.stack([2 * (f * a + cx) / (W - 1) - 1, 2 * (f * b + cy) / (H - 1) - 1], -1).view(1, H, W, 2)
    gradient = torch.nn.functional.grid_sample(image_gradient(source), grid, align_corners=True).flatten(2)
    fx = fy = K[:, 0, 0, None]
    J = _jacobian(gradient, a, b, iz, fx, fy, (T[:, :3, 3], factor, ray) if translation_only else None)
    inside = ((grid.view(1, -1, 2).abs() < 0.9).all(-1))[0]  # away from the border (replicated gradient there)
    assert J.shape == (1, n, H * W) and inside.sum() > 0.5 * H * W
    for k in range(n):  # the bilinear slope is first order: 2-3.5 % here, halved at half the image's frequencies
        error = (J[0, k, inside] - numeric[0, k, inside]).norm() / numeric[0, k, inside].norm()
        assert error < 0.05, f"column {k}: relative error {float(error):.3f}"
