"""Direct photometric alignment: refine a frame-to-frame motion on a depth map by minimising the photometric error.

The pose network's motions are biased: it under-reports rotation, least about the optical axis (rotation gains
0.6-0.9, README, issue 4), and the calibration's rotation follows that bias. With the network's own depth, the
motion that best explains the two images is found directly: the source image is warped into the target view
(:func:`~ocalib.losses.warp.inverse_warp`) and the training loss, 0.85 SSIM + 0.15 L1 over the valid pixels
(:func:`~ocalib.losses.photometric.photometric_error`), is minimised over a 6-DoF correction by L-BFGS. Rotational
flow does not depend on depth, so the rotation comes out nearly unbiased even from a rough depth map; the
translation direction improves less where the depth is poor (a camera moving sideways trades its translation
against a yaw rotation through the depth's relative errors). Measured on held-out synthetic rigs: README, issue 5.

A correction is kept only where it lowers the loss and rotates by at most ``max_rotation_deg``: a wider basin
(a textureless view, a large occlusion) keeps the network's motion. L-BFGS reads its line search on the host: on
a GPU that is one synchronisation per evaluation.

Convention: ``T_source_target`` (B, 4, 4) maps target-camera points into the source camera
(``p_source = T p_target``); the correction is applied on the left, in the source camera's frame. Images
(B, 3, H, W) in [0, 1], target depth (B, 1, H, W), K (B, 3, 3) pixels with integer pixel centres, all at one
resolution.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from ocalib.losses.photometric import photometric_error
from ocalib.losses.warp import inverse_warp
from ocalib.models.pose import motion_to_pose

# L-BFGS iterations. Measured on 60 held-out handheld frames (2 cameras, 2 threads): the sideways camera's median
# rotation error is 0.58 / 0.36 / 0.29 / 0.27 deg at 10 / 15 / 30 / 100 iterations, for 0.14 / 0.19 / 0.37 / 0.50 s.
ALIGN_ITERATIONS = 30
MAX_ROTATION_DEG = 2.0  # largest accepted rotation correction (the network's per-frame errors stay below ~2.5 deg)


def photometric_cost(target: Tensor, source: Tensor, depth: Tensor, K: Tensor, T_source_target: Tensor) -> Tensor:
    """Mean photometric error (B,) of ``source`` warped into ``target``'s view, over its valid pixels."""
    warped = inverse_warp(source, depth, T_source_target, K)
    error = photometric_error(warped.image, target) * warped.mask
    return error.sum((1, 2, 3)) / warped.mask.sum((1, 2, 3)).clamp_min(1)


def align_motion(target: Tensor, source: Tensor, depth: Tensor, K: Tensor, T_source_target: Tensor,
                 iterations: int = ALIGN_ITERATIONS,
                 max_rotation_deg: float = MAX_ROTATION_DEG) -> tuple[Tensor, Tensor]:
    """Refine ``T_source_target`` (B, 4, 4) photometrically; returns the motions (B, 4, 4), in the input's dtype,
    and ``accepted`` (B,) bool (False: the input motion is returned). Each of the B problems is solved on its own;
    gradients flow to ``T_source_target`` through the correction held fixed."""
    B = target.shape[0]
    if not (target.dim() == 4 and target.shape == source.shape and depth.shape == (B, 1, *target.shape[2:])
            and K.shape == (B, 3, 3) and T_source_target.shape == (B, 4, 4)):
        raise ValueError(f"align_motion: expected target and source (B, C, H, W), depth (B, 1, H, W), K (B, 3, 3) and "
                         f"T_source_target (B, 4, 4), got {tuple(target.shape)}, {tuple(source.shape)}, "
                         f"{tuple(depth.shape)}, {tuple(K.shape)}, {tuple(T_source_target.shape)}")
    with torch.inference_mode(False), torch.enable_grad():  # the caller may stream under inference mode
        problems = [[x[b : b + 1].detach().clone().float() for x in (target, source, depth, K, T_source_target)]
                    for b in range(B)]
        corrections = [_solve(*problem, iterations) for problem in problems]
    limit = math.radians(max_rotation_deg)
    accepted = [c is not None and float(c[0, :3].norm()) <= limit for c in corrections]
    xi = torch.cat([c if ok else torch.zeros(1, 6, device=target.device) for c, ok in zip(corrections, accepted)])
    out = motion_to_pose(xi.to(T_source_target.dtype)) @ T_source_target
    accepted = torch.tensor(accepted, dtype=torch.bool, device=target.device)
    return out, accepted


def _solve(target: Tensor, source: Tensor, depth: Tensor, K: Tensor, T: Tensor, iterations: int) -> Tensor | None:
    """The correction (1, 6) (axis-angle, translation) that lowers the cost, or None."""
    xi = torch.zeros(1, 6, dtype=target.dtype, device=target.device, requires_grad=True)
    cost = lambda: photometric_cost(target, source, depth, K, motion_to_pose(xi) @ T).sum()  # noqa: E731
    optimiser = torch.optim.LBFGS([xi], lr=1, max_iter=iterations, line_search_fn="strong_wolfe")

    def closure():
        optimiser.zero_grad()
        value = cost()
        value.backward()
        return value

    with torch.no_grad():
        before = cost()
    optimiser.step(closure)
    with torch.no_grad():
        after = cost()
    xi = xi.detach()
    return xi if bool(torch.isfinite(xi).all() & (after < before)) else None
