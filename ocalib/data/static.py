"""Static frames: snippets whose frames barely differ (the camera stood still), and sequences that do not move.

Convention: the motion of a snippet is the mean absolute difference of grey thumbnails (values in [0, 1])
between the target frame and its sources, averaged over pixels and sources.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from ocalib.data.image_io import read_image
from ocalib.data.sequence import Sequence
from ocalib.errors import InputError

STATIC_THRESHOLD = 1e-3  # mean absolute grey difference below which two frames count as identical
STATIC_SAMPLES = 8  # frames compared with the first by :func:`check_motion`


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


def check_motion(sequence: Sequence, samples: int = STATIC_SAMPLES) -> None:
    """Raise InputError when a camera's frames all look the same (no motion: ego-motion is undefined).

    Compares grey thumbnails of up to ``samples`` evenly spaced frames with the first one; also refuses
    sequences of fewer than 2 frames.
    """
    frames = sequence.common  # cameras with their own frames: those every camera has
    if frames < 2:
        raise InputError(f"{sequence.path}: {frames} frame(s); ego-motion needs at least 2")
    index = np.unique(np.linspace(0, frames - 1, min(samples, frames)).round().astype(int))
    for cam in sequence.cameras:
        thumbs = thumbnails([cam.images[i] for i in index])
        change = float((thumbs[1:] - thumbs[:1]).abs().mean((-2, -1)).max())
        if change < STATIC_THRESHOLD:
            raise InputError(
                f"{cam.images[0].parent}: camera {cam.name} shows no motion (frames "
                f"{', '.join(map(str, index))} of {frames} are identical, mean difference "
                f"{change:.2g}); ego-motion cannot be estimated from a still camera"
            )
