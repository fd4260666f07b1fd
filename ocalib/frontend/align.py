"""Direct photometric alignment: refine a frame-to-frame motion on a depth map by minimising the photometric error.

The pose network's motions are biased: it under-reports rotation, least about the optical axis (rotation gains
0.6-0.9, docs/results-egomotion.md), and the calibration's rotation follows that bias. With the network's own depth, the
motion that best explains the two images is found directly: the source image is warped into the target view and
the grey-level residual over the valid pixels (in front of the source camera, inside its image) is minimised over
a 6-DoF correction by Gauss-Newton, coarse to fine, with Huber weights, the whole batch at once (analytic
Jacobian: the source's Sobel gradient times the projection's derivative). Rotational flow does not depend on
depth, so the rotation comes out nearly unbiased even from a rough depth map; the translation direction improves
less where the depth is poor (a camera moving sideways trades its translation against a yaw rotation through the
depth's relative errors). Measured on held-out synthetic rigs: docs/results-egomotion.md, docs/results-calibrate.md.

A correction is kept only where it lowers the residual and rotates by at most ``max_rotation_deg``: a wider basin
(a textureless view, a large occlusion) keeps the network's motion. Over a stream (:class:`StreamAligner`) each
problem also starts from its previous refined motion (constant velocity): on a car's sideways camera the network's
translation is tens of degrees off, outside the basin (measured: the median direction error there fell from 11
to 7 deg). The iterations run on the input's device with no host synchronisation. :func:`align_translation`
refines the translation alone, for a camera whose rotation is known from a rig's other camera, with the depth's
error across the image solved as a tilt (measured: the car's sideways camera's direction 5.5-8.2 -> 1.6-2.9 deg
a frame).

Convention: ``T_source_target`` (B, 4, 4) maps target-camera points into the source camera
(``p_source = T p_target``); the correction is applied on the left, in the source camera's frame. Images
(B, C, H, W) in [0, 1], target depth (B, 1, H, W), K (B, 3, 3) pixels with integer pixel centres, all at one
resolution.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from kornia.geometry.depth import depth_to_3d_v2
from torch import Tensor

from ocalib.data.intrinsics import resize_intrinsics
from ocalib.geometry.constants import constant_cache
from ocalib.geometry.pose import invert_pose
from ocalib.geometry.quaternion import rotation_angle
from ocalib.losses.photometric import photometric_error
from ocalib.losses.warp import MIN_Z, inverse_warp
from ocalib.models.pose import motion_to_pose

GN_ITERATIONS = (5, 5, 5)  # Gauss-Newton steps at a quarter, half, then full resolution
HUBER = 0.05  # grey levels: residuals beyond it are down-weighted
DAMPING = 1e-3  # Levenberg damping, relative to the normal matrix's diagonal
MAX_ROTATION_DEG = 2.0  # largest accepted rotation correction (the network's per-frame errors stay below ~2.5 deg)
MAX_TILT = (0.2, 0.3)  # largest inverse-depth tilt (a, b) of align_translation (measured on the network's depth: ~0.05)


def photometric_cost(target: Tensor, source: Tensor, depth: Tensor, K: Tensor, T_source_target: Tensor) -> Tensor:
    """Mean photometric error (B,) of ``source`` warped into ``target``'s view, over its valid pixels."""
    warped = inverse_warp(source, depth, T_source_target, K)
    error = photometric_error(warped.image, target) * warped.mask
    return error.sum((1, 2, 3)) / warped.mask.sum((1, 2, 3)).clamp_min(1)


def align_motion(
    target: Tensor,
    source: Tensor,
    depth: Tensor,
    K: Tensor,
    T_source_target: Tensor,
    prior: Tensor | None = None,
    iterations: tuple[int, ...] = GN_ITERATIONS,
    max_rotation_deg: float = MAX_ROTATION_DEG,
) -> tuple[Tensor, Tensor]:
    """Refine ``T_source_target`` (B, 4, 4) photometrically; returns the motions (B, 4, 4), in the input's dtype,
    and ``accepted`` (B,) bool (False: the input motion is returned).

    ``prior`` (B, 4, 4), optional: a second start, e.g. the previous frame's refined motion (a constant-velocity
    model, :class:`StreamAligner`); both starts descend the coarse levels in one batch, and at full resolution only
    the better of them (or the input, if better still) is refined further.
    ``iterations[k]``: Gauss-Newton steps at pyramid level ``len(iterations) - 1 - k`` (level l at 1/2^l of the
    input resolution, coarsest first). Each of the B problems is solved on its own, all in one batch; gradients
    flow to ``T_source_target`` through the correction held fixed.
    """
    _check_shapes(target, source, depth, K, T_source_target, prior)
    with torch.no_grad(), torch.autocast(target.device.type, enabled=False):  # float32 under mixed precision too
        start = T_source_target.detach().float()
        starts = [start] if prior is None else [start, prior.detach().float()]
        refined, improved = _coarse_to_fine(target, source, depth, K, starts, iterations)
        correction = refined @ invert_pose(start)
        angle = rotation_angle(correction[:, :3, :3].double())
        accepted = improved & (angle <= math.radians(max_rotation_deg)) & torch.isfinite(correction).all((1, 2))
        eye = torch.eye(4, dtype=correction.dtype, device=correction.device)
        correction = torch.where(accepted[:, None, None], correction, eye).to(T_source_target.dtype)
    return correction @ T_source_target, accepted


def align_translation(
    target: Tensor,
    source: Tensor,
    depth: Tensor,
    K: Tensor,
    T_source_target: Tensor,
    iterations: tuple[int, ...] = GN_ITERATIONS,
) -> tuple[Tensor, Tensor]:
    """Refine only the translation of ``T_source_target`` (B, 4, 4), its rotation held; returns the motions
    (B, 4, 4), in the input's dtype, and ``accepted`` (B,) bool (False: the input motion is returned).

    For a camera whose rotation is known better from elsewhere: on a rig, camera k turns by R_X^T R_0 R_X when
    camera 0 turns by R_0 (:class:`~ocalib.calibnet.OnlineCalibrationNet`). A camera moving sideways trades its
    lateral translation for a rotation about its vertical axis, and the network's depth (whose error grows across
    the image, ~13 % from edge to edge on the car's left camera) biases that trade; with the rotation held the
    translation is left, and the depth's error across the image is solved with it as a tilt of the inverse depth,
    rho' = rho (1 + a x + b y) (x, y: normalised image coordinates, |a|, |b| <= :data:`MAX_TILT`). Measured on
    the held-out cars: docs/results-calibrate.md. Gradients flow to ``T_source_target`` through the correction held fixed.
    """
    _check_shapes(target, source, depth, K, T_source_target, None)
    with torch.no_grad(), torch.autocast(target.device.type, enabled=False):
        start = T_source_target.detach().float()
        refined, improved = _coarse_to_fine(target, source, depth, K, [start], iterations, translation_only=True)
        correction = refined @ invert_pose(start)
        correction[:, :3, :3] = torch.eye(3, device=start.device)  # exactly a translation
        accepted = improved & torch.isfinite(correction).all((1, 2))
        eye = torch.eye(4, dtype=correction.dtype, device=correction.device)
        correction = torch.where(accepted[:, None, None], correction, eye).to(T_source_target.dtype)
    return correction @ T_source_target, accepted


def image_gradient(image: Tensor) -> Tensor:
    """Derivatives along u, then along v, of every channel: (B, C, H, W) -> (B, 2 C, H, W) (all d/du first).

    The normalised 3x3 Sobel filter with replicated borders, as kornia's ``spatial_gradient(normalized=True)``,
    with its kernels cached per device: no host-to-device copy in a frame on CUDA."""
    B, C, H, W = image.shape
    padded = F.pad(image.reshape(B * C, 1, H, W), (1, 1, 1, 1), mode="replicate")
    return F.conv2d(padded, _sobel(image.dtype, image.device)).reshape(B, C, 2, H, W).transpose(1, 2).flatten(1, 2)


@constant_cache
def _sobel(dtype: torch.dtype, device: torch.device) -> Tensor:
    """The normalised Sobel kernels d/du and d/dv, (2, 1, 3, 3)."""
    k = torch.tensor([[-1.0, 0.0, 1.0], [-2.0, 0.0, 2.0], [-1.0, 0.0, 1.0]], dtype=torch.float64) / 8
    return torch.stack([k, k.T])[:, None].to(dtype=dtype, device=device)


def _check_shapes(target: Tensor, source: Tensor, depth: Tensor, K: Tensor, T: Tensor, prior: Tensor | None) -> None:
    B = target.shape[0]
    if not (
        target.dim() == 4
        and target.shape == source.shape
        and depth.shape == (B, 1, *target.shape[2:])
        and K.shape == (B, 3, 3)
        and T.shape == (B, 4, 4)
        and (prior is None or prior.shape == (B, 4, 4))
    ):
        raise ValueError(
            f"align: expected target and source (B, C, H, W), depth (B, 1, H, W), K (B, 3, 3), "
            f"T_source_target and prior (B, 4, 4), got {tuple(target.shape)}, {tuple(source.shape)}, "
            f"{tuple(depth.shape)}, {tuple(K.shape)}, {tuple(T.shape)}, "
            f"{None if prior is None else tuple(prior.shape)}"
        )


def _coarse_to_fine(
    target: Tensor,
    source: Tensor,
    depth: Tensor,
    K: Tensor,
    starts: list[Tensor],
    iterations: tuple[int, ...],
    translation_only: bool = False,
    huber: float = HUBER,
    damping: float = DAMPING,
) -> tuple[Tensor, Tensor]:
    """Gauss-Newton over the pyramid from each of the ``starts`` (B, 4, 4) (the first: the input motion) ->
    the motion of lowest residual at full resolution (B, 4, 4) float32 and whether it beats the input's (B,) bool.

    Every start descends the coarse levels (in one batch); at full resolution the best of them and the input
    compete, and only the winner is refined further. ``translation_only``: the rotation is held and the depth's
    inverse tilt is solved with the translation (:func:`align_translation`)."""
    target, source = (x.detach().float().mean(1, keepdim=True) for x in (target, source))  # grey
    depth, K = depth.detach().float(), K.detach().float()
    H, W, S = *target.shape[-2:], len(starts)
    T = torch.cat(starts)  # (S B, 4, 4)
    tilt = T.new_zeros(T.shape[0], 2)
    options = (translation_only, huber, damping)
    for level in reversed(range(1, len(iterations))):
        size = (max(1, H >> level), max(1, W >> level))
        pyramid = [F.interpolate(x, size, mode="area") for x in (target, source)]
        pyramid.append(1 / F.interpolate(1 / depth.clamp(min=MIN_Z), size, mode="area"))
        pyramid.append(resize_intrinsics(K, (H, W), size))
        pyramid = [x.repeat(S, *[1] * (x.dim() - 1)) for x in pyramid]
        T, tilt, _ = _gauss_newton(*pyramid, [(T, tilt)], iterations[len(iterations) - 1 - level], *options)
    candidates = [(starts[0], starts[0].new_zeros(len(starts[0]), 2)), *zip(T.chunk(S), tilt.chunk(S))]
    T, _, best = _gauss_newton(target, source, depth, K, candidates, iterations[-1], *options)
    return T, best > 0


def _gauss_newton(
    target: Tensor,
    source: Tensor,
    depth: Tensor,
    K: Tensor,
    candidates: list[tuple[Tensor, Tensor]],
    iterations: int,
    translation_only: bool,
    huber: float,
    damping: float,
) -> tuple[Tensor, Tensor, Tensor]:
    """Gauss-Newton from the best of the ``candidates`` (motion (B, 4, 4), inverse-depth tilt (B, 2)) -> the
    motion and tilt of lowest mean absolute residual among the candidates and the iterates, and its index (B,) in
    that order (0: the first candidate). ``translation_only``: the unknowns are the translation and the tilt."""
    B, C, H, W = target.shape
    # pixels along the last axis, coordinates along the second: every per-pixel term below is a contiguous row
    points = depth_to_3d_v2(depth[:, 0], K).reshape(B, -1, 3).transpose(1, 2)  # (B, 3, N) target camera
    ray = points[:, :2] / points[:, 2:].clamp(min=MIN_Z)  # (B, 2, N) normalised image coordinates
    # source intensity, then its derivatives along u and along v (per pixel), sampled together
    stacked = torch.cat([source, image_gradient(source)], 1)
    fx, fy, cx, cy = K[:, 0, 0, None], K[:, 1, 1, None], K[:, 0, 2, None], K[:, 1, 2, None]
    (best, best_tilt), best_cost = candidates[-1], torch.full((B,), math.inf, device=target.device)
    index = torch.zeros(B, dtype=torch.long, device=target.device)
    queue, evaluations = list(candidates), len(candidates) + (len(candidates) > 1) + iterations
    for it in range(evaluations):
        T, tilt = queue.pop(0)
        if translation_only:
            factor = (1 + (ray * tilt[..., None]).sum(1, keepdim=True)).clamp(min=0.2)  # (B, 1, N): rho' / rho
        X = torch.baddbmm(T[:, :3, 3:], T[:, :3, :3], points / factor if translation_only else points)  # (B, 3, N)
        z = X[:, 2].clamp(min=MIN_Z)
        iz = 1 / z
        a, b = X[:, 0] * iz, X[:, 1] * iz  # (B, N) normalised coordinates in the source camera
        u, v = 2 * (fx * a + cx) / max(W - 1, 1) - 1, 2 * (fy * b + cy) / max(H - 1, 1) - 1  # grid_sample's
        valid = ((u.abs() <= 1) & (v.abs() <= 1) & (X[:, 2] > MIN_Z)).to(target.dtype)  # (B, N)
        sampled = F.grid_sample(stacked, torch.stack([u, v], -1).view(B, H, W, 2), align_corners=True).flatten(2)
        r = (sampled[:, :C] - target.flatten(2)) * valid[:, None]  # (B, C, N)
        cost = r.abs().sum((1, 2)) / (valid.sum(1) * C).clamp(min=1)
        improved = cost < best_cost
        best = torch.where(improved[:, None, None], T, best)
        best_tilt = torch.where(improved[:, None], tilt, best_tilt)
        best_cost = torch.where(improved, cost, best_cost)
        index = torch.where(improved, it, index)
        if queue or it == evaluations - 1:
            continue
        if it == len(candidates) - 1 and len(candidates) > 1:  # descend from the best candidate
            queue.append((best, best_tilt))
            continue
        J = _jacobian(sampled[:, C:], a, b, iz, fx, fy, (T[:, :3, 3], factor, ray) if translation_only else None)
        Jw = J * ((huber / r.abs().clamp(min=huber)) * valid[:, None]).flatten(1)[:, None]  # Huber weights
        A = Jw @ J.transpose(1, 2)  # (B, 6, 6)
        g = Jw @ r.flatten(1)[..., None]
        A = A + damping * torch.diag_embed(A.diagonal(dim1=1, dim2=2)) + 1e-9 * torch.eye(A.shape[-1], device=A.device)
        step = -torch.linalg.solve_ex(A, g)[0][..., 0]  # _ex: no host round-trip to check the factorisation
        step = torch.where(torch.isfinite(step).all(-1, keepdim=True), step, torch.zeros_like(step))
        if translation_only:
            tilt = torch.stack([(tilt + step[:, 3:]).select(1, i).clamp(-m, m) for i, m in enumerate(MAX_TILT)], 1)
            step = F.pad(step[:, :3], (3, 0))
        queue.append((motion_to_pose(step) @ T, tilt))
    return best, best_tilt, index


def _jacobian(
    gradient: Tensor,
    a: Tensor,
    b: Tensor,
    iz: Tensor,
    fx: Tensor,
    fy: Tensor,
    tilt: tuple[Tensor, Tensor, Tensor] | None = None,
) -> Tensor:
    """Derivative of the residual (B, 6, C N) with respect to a correction ``exp([w, v])`` applied on the left of the
    motion (w: rotation, v: translation, in the source camera), per pixel: the image gradient times d(a, b)/d(w, v),
    with d(a, b)/dX = [[1/z, 0, -a/z], [0, 1/z, -b/z]] and dX/d(w, v) = [-[X]x, I].

    ``gradient`` (B, 2 C, N): the source's d/du of every channel, then d/dv, sampled at the projections; ``a``,
    ``b`` (B, N): the points' normalised coordinates x/z, y/z in the source camera; ``iz`` (B, N): 1/z; ``fx``, ``fy``
    (B, 1). ``tilt``: (translation (B, 3), factor (B, 1, N), ray (B, 2, N)) for :func:`align_translation`: the
    columns are then d/dv and d/d(tilt) (B, 5, C N), d(u, v)/d(tilt) = (d(u, v)/dv . v) (x, y) / factor (moving X
    along its own ray does not move its projection).
    """
    C = gradient.shape[1] // 2
    gu, gv = gradient[:, :C] * fx[..., None], gradient[:, C:] * fy[..., None]  # per unit of a, b: (B, C, N)
    a, b, iz = a[:, None], b[:, None], iz[:, None]
    J = [gu * iz, gv * iz, -(gu * a + gv * b) * iz]  # translation
    if tilt is not None:
        t, factor, ray = tilt
        along = sum(d * t[:, k, None, None] for k, d in enumerate(J)) / factor  # (B, C, N)
        J += [along * ray[:, :1], along * ray[:, 1:]]
    else:
        ab = a * b
        J = [-gu * ab - gv * (1 + b * b), gu * (1 + a * a) + gv * ab, gv * a - gu * b] + J
    return torch.stack(J, 1).flatten(2)


class StreamAligner(torch.nn.Module):
    """:func:`align_motion` over ``streams`` streams of frame pairs: each problem also starts from its own previous
    refined motion (a constant-velocity model; the identity, no motion, before the first call and after
    :meth:`reset`).

    The pose network's translation can be far off on a camera moving sideways (tens of degrees), outside the
    Gauss-Newton basin; the previous frame's refined motion is usually close. The B = ``streams`` problems of every
    call are the same streams, in the same order. The previous motions are a buffer: ``state_dict`` and ``.to``
    carry them.
    """

    def __init__(
        self, streams: int, iterations: tuple[int, ...] = GN_ITERATIONS, max_rotation_deg: float = MAX_ROTATION_DEG
    ):
        super().__init__()
        self.iterations, self.max_rotation_deg = iterations, max_rotation_deg
        self.register_buffer("previous", torch.eye(4).expand(streams, 4, 4).clone())

    def reset(self) -> None:
        self.previous = torch.eye(4, device=self.previous.device).expand_as(self.previous).clone()

    def forward(
        self, target: Tensor, source: Tensor, depth: Tensor, K: Tensor, T_source_target: Tensor
    ) -> tuple[Tensor, Tensor]:
        """As :func:`align_motion`, with the previous call's refined motions (B, 4, 4) as the prior."""
        refined, accepted = align_motion(
            target, source, depth, K, T_source_target, self.previous, self.iterations, self.max_rotation_deg
        )
        self.previous = refined.detach().float()
        return refined, accepted
