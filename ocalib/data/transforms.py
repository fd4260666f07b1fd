"""Geometric transforms of a snippet that keep its intrinsics, depth and poses consistent.

A sample is a dict with ``image`` (S, 3, H, W), ``K`` (3, 3) and optionally ``depth`` (S, 1, H, W) and
``poses`` (S, 4, 4); other keys pass through unchanged.

Convention: K in pixels with integer pixel centres; resizing follows ``F.interpolate(align_corners=False)``
(u -> (u + 0.5) s - 0.5), depth is resized by nearest neighbour (``nearest-exact``, same mapping) so no
depth is invented across edges.
"""

from __future__ import annotations

import torch.nn.functional as F

from ocalib.data.intrinsics import crop_intrinsics, flip_intrinsics, flip_pose, resize_intrinsics


def resize(sample: dict, size: tuple[int, int]) -> dict:
    """Resize every frame to ``size`` (H, W), scaling K."""
    old = tuple(sample["image"].shape[-2:])
    size = tuple(size)
    if old == size:
        return sample
    out = dict(sample)
    antialias = size[0] < old[0] or size[1] < old[1]
    out["image"] = F.interpolate(
        sample["image"], size, mode="bilinear", align_corners=False, antialias=antialias
    ).clamp(0, 1)
    out["K"] = resize_intrinsics(sample["K"], old, size)
    if "depth" in sample:
        out["depth"] = F.interpolate(sample["depth"], size, mode="nearest-exact")
    return out


def crop(sample: dict, x0: int, y0: int, height: int, width: int) -> dict:
    """Crop every frame to the window with top-left pixel (x0, y0) and size (height, width)."""
    out = dict(sample)
    window = (..., slice(y0, y0 + height), slice(x0, x0 + width))
    out["image"] = sample["image"][window]
    out["K"] = crop_intrinsics(sample["K"], x0, y0)
    if "depth" in sample:
        out["depth"] = sample["depth"][window]
    return out


def hflip(sample: dict) -> dict:
    """Mirror every frame left-right: K (cx' = W - 1 - cx) and poses (M T M) follow the mirrored world."""
    out = dict(sample)
    out["image"] = sample["image"].flip(-1)
    out["K"] = flip_intrinsics(sample["K"], sample["image"].shape[-1])
    if "depth" in sample:
        out["depth"] = sample["depth"].flip(-1)
    if "poses" in sample:
        out["poses"] = flip_pose(sample["poses"])
    return out
