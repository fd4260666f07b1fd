"""Depth network: residual encoder, monodepth2-style decoder with skip connections, sigmoid disparity at
4 scales, and the disparity-to-depth mapping.

Convention: input images (B, 3, H, W) in [0, 1] (any H, W); disparities in (0, 1), scale s at H/2^s.
Depth is in network units (monodepth2: ``1 / (1/max_depth + (1/min_depth - 1/max_depth) disp)``).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ocalib.models.layers import ConvELU, Encoder

MEAN, STD = 0.45, 0.225  # input normalisation (monodepth2)
INIT_DISPARITY = 0.1  # initial sigmoid output (depth ~1 with the default range; 0.5 gives ~0.2, near the minimum,
# where the sigmoid saturated in training: measured, the near field stuck at the minimum depth)


def disp_to_depth(disp: Tensor, min_depth: float = 0.1, max_depth: float = 100.0) -> Tensor:
    """Sigmoid disparity (any shape) -> depth in [min_depth, max_depth]."""
    lo, hi = 1.0 / max_depth, 1.0 / min_depth
    return 1.0 / (lo + (hi - lo) * disp)


class DepthNet(nn.Module):
    """Encoder-decoder: ``forward(image)`` (B, 3, H, W) -> list of ``scales`` disparities (B, 1, H/2^s, W/2^s).

    ``widths``: encoder channels at 1/2 .. 1/32; ``decoder``: decoder channels at 1 .. 1/16;
    ``blocks``: residual blocks per encoder stage.
    """

    def __init__(self, widths=(16, 24, 32, 64, 96), decoder=(8, 16, 24, 32, 64), blocks: int = 1, scales: int = 4):
        super().__init__()
        self.encoder = Encoder(3, widths, blocks)
        self.scales = scales
        n = len(decoder)
        # level i (resolution 1/2^i): upconv0 from the coarser level, upconv1 after concatenating the skip.
        self.upconv0 = nn.ModuleList(
            ConvELU(widths[-1] if i == n - 1 else decoder[i + 1], decoder[i]) for i in range(n)
        )
        self.upconv1 = nn.ModuleList(
            ConvELU(decoder[i] + (widths[i - 1] if i > 0 else 0), decoder[i]) for i in range(n)
        )
        self.heads = nn.ModuleList(nn.Conv2d(decoder[s], 1, 3, padding=1) for s in range(scales))
        for head in self.heads:  # start at disparity ~INIT_DISPARITY: depth ~1, mid-range in log depth
            nn.init.constant_(head.bias, math.log(INIT_DISPARITY / (1 - INIT_DISPARITY)))

    def forward(self, image: Tensor) -> list[Tensor]:
        features = self.encoder((image - MEAN) / STD)
        x = features[-1]
        size = image.shape[-2:]
        disps = {}
        for i in reversed(range(len(self.upconv0))):
            x = self.upconv0[i](x)
            skip = features[i - 1] if i > 0 else None
            target = skip.shape[-2:] if skip is not None else size
            x = F.interpolate(x, size=target, mode="nearest")
            x = self.upconv1[i](torch.cat([x, skip], 1) if skip is not None else x)
            if i < self.scales:
                disps[i] = torch.sigmoid(self.heads[i](x))
        return [disps[s] for s in range(self.scales)]
