"""Direct photometric alignment: refine a frame-to-frame motion on a depth map by minimising the photometric error.

The pose network's motions are biased: it under-reports rotation, least about the optical axis (rotation gains
0.6-0.9, README, issue 4), and the calibration's rotation follows that bias. With the network's own depth, the
motion that best explains the two images is found directly: the source image is warped into the target view and
the grey-level residual over the valid pixels (in front of the source camera, inside its image) is minimised over
a 6-DoF correction by Gauss-Newton, coarse to fine, with Huber weights, the whole batch at once (analytic
Jacobian: the source's Sobel gradient times the projection's derivative). Rotational flow does not depend on
depth, so the rotation comes out nearly unbiased even from a rough depth map; the translation direction improves
less where the depth is poor (a camera moving sideways trades its translation against a yaw rotation through the
depth's relative errors). Measured on held-out synthetic rigs: README, issues 4 and 5.

A correction is kept only where it lowers the residual and rotates by at most ``max_rotation_deg``: a wider basin
(a textureless view, a large occlusion) keeps the network's motion. Over a stream (:class:`StreamAligner`) each
problem also starts from its previous refined motion (constant velocity): on a car's sideways camera the network's
translation is tens of degrees off, outside the basin (session 13: the median direction error there fell from 11
to 7 deg). The iterations run on the input's device with no host synchronisation.

Convention: ``T_source_target`` (B, 4, 4) maps target-camera points into the source camera
(``p_source = T p_target``); the correction is applied on the left, in the source camera's frame. Images
(B, C, H, W) in [0, 1], target depth (B, 1, H, W), K (B, 3, 3) pixels with integer pixel centres, all at one
resolution.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from kornia.filters import spatial_gradient
from kornia.geometry.depth import depth_to_3d_v2
from torch import Tensor

from ocalib.data.intrinsics import resize_intrinsics
from ocalib.losses.photometric import photometric_error
from ocalib.losses.warp import MIN_Z, inverse_warp
from ocalib.geometry.pose import invert_pose
from ocalib.geometry.quaternion import rotation_angle
from ocalib.models.pose import motion_to_pose

GN_ITERATIONS = (5, 5, 5)  # Gauss-Newton steps at a quarter, half, then full resolution
HUBER = 0.05  # grey levels: residuals beyond it are down-weighted
DAMPING = 1e-3  # Levenberg damping, relative to the normal matrix's diagonal
MAX_ROTATION_DEG = 2.0  # largest accepted rotation correction (the network's per-frame errors stay below ~2.5 deg)


def photometric_cost(target: Tensor, source: Tensor, depth: Tensor, K: Tensor, T_source_target: Tensor) -> Tensor:
    """Mean photometric error (B,) of ``source`` warped into ``target``'s view, over its valid pixels."""
    warped = inverse_warp(source, depth, T_source_target, K)
    error = photometric_error(warped.image, target) * warped.mask
    return error.sum((1, 2, 3)) / warped.mask.sum((1, 2, 3)).clamp_min(1)


def align_motion(target: Tensor, source: Tensor, depth: Tensor, K: Tensor, T_source_target: Tensor,
                 prior: Tensor | None = None, iterations: tuple[int, ...] = GN_ITERATIONS,
                 max_rotation_deg: float = MAX_ROTATION_DEG) -> tuple[Tensor, Tensor]:
    """Refine ``T_source_target`` (B, 4, 4) photometrically; returns the motions (B, 4, 4), in the input's dtype,
    and ``accepted`` (B,) bool (False: the input motion is returned).

    ``prior`` (B, 4, 4), optional: a second start, e.g. the previous frame's refined motion (a constant-velocity
    model, :class:`StreamAligner`); both starts descend the coarse levels in one batch, and at full resolution only
    the better of them (or the input, if better still) is refined further.
    ``iterations[k]``: Gauss-Newton steps at pyramid level ``len(iterations) - 1 - k`` (level l at 1/2^l of the
    input resolution, coarsest first). Each of the B problems is solved on its own, all in one batch; gradients
    flow to ``T_source_target`` through the correction held fixed.
    """
    B = target.shape[0]
    if not (target.dim() == 4 and target.shape == source.shape and depth.shape == (B, 1, *target.shape[2:])
            and K.shape == (B, 3, 3) and T_source_target.shape == (B, 4, 4)
            and (prior is None or prior.shape == (B, 4, 4))):
        raise ValueError(f"align_motion: expected target and source (B, C, H, W), depth (B, 1, H, W), K (B, 3, 3), "
                         f"T_source_target and prior (B, 4, 4), got {tuple(target.shape)}, {tuple(source.shape)}, "
                         f"{tuple(depth.shape)}, {tuple(K.shape)}, {tuple(T_source_target.shape)}, "
                         f"{None if prior is None else tuple(prior.shape)}")
    with torch.no_grad():
        start = T_source_target.detach().float()
        starts = [start] if prior is None else [start, prior.detach().float()]
        refined, improved = _coarse_to_fine(target, source, depth, K, starts, iterations)
        correction = refined @ invert_pose(start)
        angle = rotation_angle(correction[:, :3, :3].double())
        accepted = improved & (angle <= math.radians(max_rotation_deg)) & torch.isfinite(correction).all((1, 2))
        eye = torch.eye(4, dtype=correction.dtype, device=correction.device)
        correction = torch.where(accepted[:, None, None], correction, eye).to(T_source_target.dtype)
    return correction @ T_source_target, accepted


def _coarse_to_fine(target: Tensor, source: Tensor, depth: Tensor, K: Tensor, starts: list[Tensor],
                    iterations: tuple[int, ...], huber: float = HUBER, damping: float = DAMPING) -> tuple[Tensor, Tensor]:
    """Gauss-Newton over the pyramid from each of the ``starts`` (B, 4, 4) (the first: the input motion) ->
    the motion of lowest residual at full resolution (B, 4, 4) float32 and whether it beats the input's (B,) bool.

    Every start descends the coarse levels (in one batch); at full resolution the best of them and the input
    compete, and only the winner is refined further."""
    target, source = (x.detach().float().mean(1, keepdim=True) for x in (target, source))  # grey
    depth, K = depth.detach().float(), K.detach().float()
    H, W, S = *target.shape[-2:], len(starts)
    T = torch.cat(starts)  # (S B, 4, 4)
    for level in reversed(range(1, len(iterations))):
        size = (max(1, H >> level), max(1, W >> level))
        pyramid = [F.interpolate(x, size, mode="area") for x in (target, source)]
        pyramid.append(1 / F.interpolate(1 / depth.clamp(min=MIN_Z), size, mode="area"))
        pyramid.append(resize_intrinsics(K, (H, W), size))
        pyramid = [x.repeat(S, *[1] * (x.dim() - 1)) for x in pyramid]
        T, _ = _gauss_newton(*pyramid, [T], iterations[len(iterations) - 1 - level], huber, damping)
    T, best = _gauss_newton(target, source, depth, K, [starts[0], *T.chunk(S)], iterations[-1], huber, damping)
    return T, best > 0


def _gauss_newton(target: Tensor, source: Tensor, depth: Tensor, K: Tensor, candidates: list[Tensor],
                  iterations: int, huber: float, damping: float) -> tuple[Tensor, Tensor]:
    """Gauss-Newton from the best of the ``candidates`` -> the motion (B, 4, 4) of lowest mean absolute residual
    among the candidates and the iterates, and its index (B,) in that order (0: the first candidate)."""
    B, C, H, W = target.shape
    points = depth_to_3d_v2(depth[:, 0], K).reshape(B, -1, 3)  # target camera
    # source intensity, then its derivatives along u and along v (per pixel), sampled together
    stacked = torch.cat([source, spatial_gradient(source, normalized=True).transpose(1, 2).flatten(1, 2)], 1)
    fx, fy, cx, cy = K[:, 0, 0, None], K[:, 1, 1, None], K[:, 0, 2, None], K[:, 1, 2, None]
    best, best_cost = candidates[-1], torch.full((B,), math.inf, device=target.device)
    index = torch.zeros(B, dtype=torch.long, device=target.device)
    queue, evaluations = list(candidates), len(candidates) + (len(candidates) > 1) + iterations
    for it in range(evaluations):
        T = queue.pop(0)
        X = points @ T[:, :3, :3].transpose(1, 2) + T[:, None, :3, 3]  # (B, N, 3) in the source camera
        z = X[..., 2].clamp(min=MIN_Z)
        u, v = fx * X[..., 0] / z + cx, fy * X[..., 1] / z + cy
        grid = torch.stack([2 * u / max(W - 1, 1) - 1, 2 * v / max(H - 1, 1) - 1], -1)
        valid = ((grid.abs() <= 1).all(-1) & (X[..., 2] > MIN_Z)).to(target.dtype)  # (B, N)
        sampled = F.grid_sample(stacked, grid.view(B, H, W, 2), align_corners=True).flatten(2)  # (B, 3C, N)
        r = (sampled[:, :C] - target.flatten(2)) * valid[:, None]  # (B, C, N)
        cost = r.abs().sum((1, 2)) / (valid.sum(1) * C).clamp(min=1)
        improved = cost < best_cost
        best = torch.where(improved[:, None, None], T, best)
        best_cost = torch.where(improved, cost, best_cost)
        index = torch.where(improved, it, index)
        if queue or it == evaluations - 1:
            continue
        if it == len(candidates) - 1 and len(candidates) > 1:  # descend from the best candidate
            queue.append(best)
            continue
        x, y, iz = X[..., 0], X[..., 1], 1 / z
        gu, gv = sampled[:, C : 2 * C] * fx[:, None], sampled[:, 2 * C :] * fy[:, None]  # per unit of x/z, y/z
        # d(x/z, y/z)/dX = [[1/z, 0, -x/z^2], [0, 1/z, -y/z^2]] times dX/d(w, v) = [-[X]x, I]
        zero = torch.zeros_like(z)
        du = torch.stack([-x * y * iz, z + x * x * iz, -y, z * iz, zero, -x * iz], -1) * iz[..., None]
        dv = torch.stack([-(z + y * y * iz), x * y * iz, x, zero, z * iz, -y * iz], -1) * iz[..., None]
        J = (gu[..., None] * du[:, None] + gv[..., None] * dv[:, None]).flatten(1, 2)  # (B, C N, 6)
        w = ((huber / r.abs().clamp(min=huber)) * valid[:, None]).flatten(1)[..., None]  # Huber weights
        A = (J * w).transpose(1, 2) @ J  # (B, 6, 6)
        g = (J * w).transpose(1, 2) @ r.flatten(1)[..., None]
        A = A + damping * torch.diag_embed(A.diagonal(dim1=1, dim2=2)) + 1e-9 * torch.eye(6, device=A.device)
        step = -torch.linalg.solve(A, g)[..., 0]
        step = torch.where(torch.isfinite(step).all(-1, keepdim=True), step, torch.zeros_like(step))
        queue.append(motion_to_pose(step) @ T)
    return best, index


class StreamAligner(torch.nn.Module):
    """:func:`align_motion` over ``streams`` streams of frame pairs: each problem also starts from its own previous
    refined motion (a constant-velocity model; the identity, no motion, before the first call and after
    :meth:`reset`).

    The pose network's translation can be far off on a camera moving sideways (tens of degrees), outside the
    Gauss-Newton basin; the previous frame's refined motion is usually close. The B = ``streams`` problems of every
    call are the same streams, in the same order. The previous motions are a buffer: ``state_dict`` and ``.to``
    carry them.
    """

    def __init__(self, streams: int, iterations: tuple[int, ...] = GN_ITERATIONS,
                 max_rotation_deg: float = MAX_ROTATION_DEG):
        super().__init__()
        self.iterations, self.max_rotation_deg = iterations, max_rotation_deg
        self.register_buffer("previous", torch.eye(4).expand(streams, 4, 4).clone())

    def reset(self) -> None:
        self.previous = torch.eye(4, device=self.previous.device).expand_as(self.previous).clone()

    def forward(self, target: Tensor, source: Tensor, depth: Tensor, K: Tensor,
                T_source_target: Tensor) -> tuple[Tensor, Tensor]:
        """As :func:`align_motion`, with the previous call's refined motions (B, 4, 4) as the prior."""
        refined, accepted = align_motion(target, source, depth, K, T_source_target, self.previous, self.iterations,
                                         self.max_rotation_deg)
        self.previous = refined.detach().float()
        return refined, accepted
