"""Static-frame filtering: find snippets whose frames barely differ (the camera stood still).

Convention: the motion of a snippet is the mean absolute difference of grey thumbnails (values in [0, 1])
between the target frame and its sources, averaged over pixels and sources.
"""

from __future__ import annotations

from pathlib import Path

import torch
import torch.nn.functional as F
from torch import Tensor

from ocalib.data.image_io import read_image


def thumbnails(paths: list[Path], width: int = 64) -> Tensor:
    """Grey thumbnails (N, h, width) of the images ``paths`` (area-averaged)."""
    thumbs = []
    for path in paths:
        grey = read_image(path).mean(0, keepdim=True)[None]
        height = max(1, round(grey.shape[-2] * width / grey.shape[-1]))
        thumbs.append(F.interpolate(grey, (height, width), mode="area")[0, 0])
    return torch.stack(thumbs)


def snippet_motion(thumbs: Tensor, targets: list[int], offsets: list[int]) -> Tensor:
    """Motion (T,) of the snippets with target frames ``targets`` and source ``offsets``."""
    t = torch.as_tensor(targets)
    diffs = [(thumbs[t] - thumbs[t + o]).abs().mean((-2, -1)) for o in offsets]
    return torch.stack(diffs).mean(0)
