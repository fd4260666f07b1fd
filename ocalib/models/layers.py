"""Building blocks of the depth and pose networks: residual encoder stages and decoder convolutions.

Convention: feature maps (B, C, H, W); every encoder stage halves H and W (rounding up).
"""

from __future__ import annotations

import torch.nn.functional as F
from torch import Tensor, nn


def conv_bn(cin: int, cout: int, stride: int = 1, kernel: int = 3) -> nn.Sequential:
    """Convolution (no bias) + batch norm."""
    return nn.Sequential(nn.Conv2d(cin, cout, kernel, stride, kernel // 2, bias=False), nn.BatchNorm2d(cout))


class BasicBlock(nn.Module):
    """ResNet basic block: two 3x3 conv-BN, a residual (1x1 conv-BN when the shape changes), ReLU."""

    def __init__(self, cin: int, cout: int, stride: int = 1):
        super().__init__()
        self.conv1, self.conv2 = conv_bn(cin, cout, stride), conv_bn(cout, cout)
        self.shortcut = conv_bn(cin, cout, stride, 1) if stride != 1 or cin != cout else nn.Identity()

    def forward(self, x: Tensor) -> Tensor:
        return F.relu(self.conv2(F.relu(self.conv1(x))) + self.shortcut(x))


class Encoder(nn.Module):
    """ResNet-like encoder: a stride-2 stem then one stage per further width, each halving the size.

    ``widths`` (C0, ..., C4): channels at 1/2, 1/4, ... 1/32 of the input; ``blocks``: basic blocks per stage
    (the first strided). ``forward`` (B, cin, H, W) -> list of the 5 feature maps, finest first.
    """

    def __init__(self, cin: int, widths: tuple[int, ...], blocks: int = 1, stem_kernel: int = 3):
        super().__init__()
        self.stem = nn.Sequential(conv_bn(cin, widths[0], 2, stem_kernel), nn.ReLU(inplace=True))
        self.stages = nn.ModuleList(
            nn.Sequential(BasicBlock(a, b, 2), *[BasicBlock(b, b) for _ in range(blocks - 1)])
            for a, b in zip(widths[:-1], widths[1:])
        )
        self.widths = tuple(widths)

    def forward(self, x: Tensor) -> list[Tensor]:
        features = [self.stem(x)]
        for stage in self.stages:
            features.append(stage(features[-1]))
        return features


class ConvELU(nn.Sequential):
    """3x3 convolution + ELU, as in the monodepth2 decoder (zero padding: reflection padding is slow on CPU)."""

    def __init__(self, cin: int, cout: int):
        super().__init__(nn.Conv2d(cin, cout, 3, padding=1), nn.ELU(inplace=True))
