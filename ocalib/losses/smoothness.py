"""Edge-aware smoothness of mean-normalised disparity (monodepth2).

Convention: disparity (B, 1, H, W), image (B, 3, H, W) at the same size; returns a scalar.
"""

from __future__ import annotations

from torch import Tensor


def edge_aware_smoothness(disp: Tensor, image: Tensor) -> Tensor:
    """``mean(|d_x d*| exp(-|d_x I|)) + mean(|d_y d*| exp(-|d_y I|))`` with ``d* = d / mean(d)`` per image."""
    d = disp / (disp.mean((2, 3), keepdim=True) + 1e-7)
    dx, dy = (d[..., :, :-1] - d[..., :, 1:]).abs(), (d[..., :-1, :] - d[..., 1:, :]).abs()
    ix = (image[..., :, :-1] - image[..., :, 1:]).abs().mean(1, keepdim=True)
    iy = (image[..., :-1, :] - image[..., 1:, :]).abs().mean(1, keepdim=True)
    return (dx * (-ix).exp()).mean() + (dy * (-iy).exp()).mean()
