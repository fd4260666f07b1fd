"""Depth consistency between frames: SC-SfMLearner's geometry consistency (Bian et al. 2019: the depth of the
target points seen from the source must agree with the source's own depth there, pixel by pixel), and its global
part alone, the log scale between the two (the depth's scale must not wander from frame to frame).

Convention: depths (B, 1, H, W) in the same (network) units.
"""

from __future__ import annotations

import torch
from torch import Tensor


def depth_inconsistency(projected: Tensor, sampled: Tensor) -> Tensor:
    """``|D_proj - D_src| / (D_proj + D_src)`` in [0, 1) (B, 1, H, W); ``1 - it`` is the self-discovered mask."""
    return (projected - sampled).abs() / (projected + sampled).clamp(min=1e-6)


def log_scale_offset(projected: Tensor, sampled: Tensor, mask: Tensor, band: float = 0.1) -> Tensor:
    """The global log-scale between two depth maps of the same points: the mean of ``log(D_proj / D_src)`` over the
    valid pixels (``mask`` (B, 1, H, W)) within ``band`` of its median (occlusions and moving surfaces left out),
    (B,). Zero when the target's depth, carried into the source camera, has the source depth's scale."""
    log_ratio = projected.clamp(min=1e-6).log() - sampled.clamp(min=1e-6).log()
    valid = mask > 0
    flat = torch.where(valid, log_ratio, torch.nan).flatten(1)
    median = flat.detach().nanmedian(1).values.nan_to_num(0.0)
    keep = (valid & ((log_ratio - median.view(-1, 1, 1, 1)).abs() < band)).to(log_ratio.dtype)
    return (log_ratio * keep).flatten(1).sum(1) / keep.flatten(1).sum(1).clamp(min=1.0)
