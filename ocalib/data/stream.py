"""A synchronised multi-camera stream for calibration: frame t of every chosen camera at once.

``RigStream(sequence)[t]`` is a dict:

* ``image`` (C, 3, H, W) float32 in [0, 1], cameras in the order of ``cameras``;
* ``K`` (C, 3, 3) float32 at the output size;
* ``poses`` (C, 4, 4) float64 camera-to-world ground truth, when the layout has it;
* ``T_cam0_cam`` (C, 4, 4) float64 extrinsics relative to the first chosen camera, when known;
* ``depth`` (C, 1, H, W) float32 metres, when the layout has it;
* ``time`` float64 seconds (the frame index when the layout has no timestamps), ``frame`` int.

Convention: camera-to-world poses; ``p_cam0 = R p_cam + t``; K with integer pixel centres.
Iterate it in order (``for frame in stream``), or wrap it in ``DataLoader(stream, batch_size=None)`` to prefetch.
"""

from __future__ import annotations

import numpy as np
import torch
from torch.utils.data import Dataset

from ocalib.data.image_io import read_depth, read_image
from ocalib.data.intrinsics import resize_intrinsics
from ocalib.data.sequence import Sequence
from ocalib.errors import InputError


class RigStream(Dataset):
    """Frames of ``sequence``'s cameras ``cameras`` (None: all), resized to ``size`` (H, W) if given."""

    def __init__(self, sequence: Sequence, cameras: list[str] | None = None, size: tuple[int, int] | None = None):
        self.sequence = sequence.select(cameras)
        self.size = size
        sizes = {cam.size for cam in self.sequence.cameras}
        if size is None and len(sizes) > 1:
            raise InputError(f"{sequence.path}: cameras have different image sizes {sorted(sizes)}; choose one size")

    @property
    def cameras(self) -> list[str]:
        return self.sequence.names

    @property
    def extrinsics(self) -> torch.Tensor | None:
        """(C, 4, 4) float64 ``T_cam0_cam``, or None when the layout does not know them."""
        Ts = [cam.T_cam0_cam for cam in self.sequence.cameras]
        return None if any(T is None for T in Ts) else torch.from_numpy(np.stack(Ts))

    def __len__(self) -> int:
        return len(self.sequence)

    def __getitem__(self, t: int) -> dict:
        if not 0 <= t < len(self):
            raise IndexError(t)
        cams = self.sequence.cameras
        sizes = [tuple(self.size or cam.size) for cam in cams]
        frame = {
            "image": torch.stack([read_image(c.images[t], c.size, s) for c, s in zip(cams, sizes)]),
            "K": torch.stack(
                [resize_intrinsics(torch.from_numpy(c.K), c.size, s) for c, s in zip(cams, sizes)]
            ).float(),
        }
        if all(cam.depth is not None for cam in cams):
            frame["depth"] = torch.stack(
                [read_depth(c.depth[t], c.depth_scale, c.size, s) for c, s in zip(cams, sizes)]
            )
        if all(cam.poses is not None for cam in cams):
            frame["poses"] = torch.from_numpy(np.stack([cam.poses[t] for cam in cams]))
        if self.extrinsics is not None:
            frame["T_cam0_cam"] = self.extrinsics
        times = self.sequence.times
        frame["time"] = float(times[t]) if times is not None else float(t)
        frame["frame"] = t
        return frame
