"""The scale gauge of a monocular depth network: a penalty that keeps its depth in the middle of its range.

Self-supervision fixes depth and motion only up to one common scale, so the network's scale is free and drifts
while it trains. Measured: without the gauge, in the range [0.1, 100], the median depth drifted from
~1 to 30-50 and up to a tenth of the pixels sat at the far end of the range (the far field crushed against it: -51 % at
40-80 m after median scaling); in the range [0.1, 1000] the whole map collapsed to the minimum depth within 3,000
steps. The penalty is zero while the mean log depth of a batch lies within a factor ``band`` of the range's
geometric centre (3.16 for [0.1, 100]: a band of [1, 10]) and grows quadratically outside, so it fixes the scale
without pulling single images to a common one.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor


def scale_gauge(depth: Tensor, min_depth: float, max_depth: float, band: float = math.sqrt(10.0)) -> Tensor:
    """Depth (any shape, > 0) -> scalar ``max(0, |mean(log depth) - log(centre)| - log(band))^2``,
    ``centre = sqrt(min_depth x max_depth)``."""
    centre = 0.5 * (math.log(min_depth) + math.log(max_depth))
    log_depth = depth.to(torch.promote_types(depth.dtype, torch.float32)).log()  # at least float32 (autocast)
    return ((log_depth.mean() - centre).abs() - math.log(band)).clamp(min=0.0).square()
