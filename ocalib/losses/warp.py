"""Inverse warping of a source frame into the target view from target depth and relative pose (kornia).

Convention: ``T_source_target`` (B, 4, 4) maps target-camera points into the source camera
(``p_source = T p_target``); K (B, 3, 3) pixels with integer pixel centres, so pixel u = 0 .. W-1 maps to
-1 .. 1 and sampling uses ``align_corners=True``.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
import torch.nn.functional as F
from kornia.geometry.camera import project_points
from kornia.geometry.conversions import normalize_pixel_coordinates
from kornia.geometry.depth import depth_to_3d_v2
from kornia.geometry.linalg import transform_points
from torch import Tensor

MIN_Z = 1e-3  # points nearer than this (or behind the source camera) are invalid


class Warp(NamedTuple):
    """Result of :func:`inverse_warp`, all at the target's resolution.

    image (B, C, H, W): the source sampled at the projections of the target pixels;
    mask (B, 1, H, W) float: 1 where the point is in front of the source camera and projects inside it;
    depth (B, 1, H, W): z of the target points in the source camera (the projected depth);
    source_depth (B, 1, H, W) or None: the source's own depth map sampled there (geometry consistency).
    """

    image: Tensor
    mask: Tensor
    depth: Tensor
    source_depth: Tensor | None


def inverse_warp(
    source: Tensor,
    depth: Tensor,
    T_source_target: Tensor,
    K: Tensor,
    source_depth: Tensor | None = None,
    padding_mode: str = "zeros",
) -> Warp:
    """Warp ``source`` (B, C, H, W) into the target view given target ``depth`` (B, 1, H, W).

    ``source_depth`` (B, 1, H, W), when given, is sampled with the same grid (bilinear).
    """
    B, _, H, W = depth.shape
    points = depth_to_3d_v2(depth[:, 0], K)  # (B, H, W, 3) in the target camera
    points = transform_points(T_source_target[:, None], points)  # in the source camera
    z = points[..., 2:]
    pixels = project_points(torch.cat([points[..., :2], z.clamp(min=MIN_Z)], -1), K[:, None])
    grid = normalize_pixel_coordinates(pixels, H, W)  # (B, H, W, 2)
    inside = (grid.abs() <= 1).all(-1, keepdim=True) & (z > MIN_Z)
    stacked = source if source_depth is None else torch.cat([source, source_depth], 1)
    sampled = F.grid_sample(stacked, grid, mode="bilinear", padding_mode=padding_mode, align_corners=True)
    image, sampled_depth = (sampled, None) if source_depth is None else (sampled[:, :-1], sampled[:, -1:])
    return Warp(image, inside.permute(0, 3, 1, 2).to(source.dtype), z.permute(0, 3, 1, 2), sampled_depth)
