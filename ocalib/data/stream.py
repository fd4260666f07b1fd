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
from ocalib.data.sequence import Sequence
from ocalib.data.transforms import resize
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
        views = []
        for cam in self.sequence.cameras:
            view = {"image": read_image(cam.images[t], cam.size)[None], "K": torch.from_numpy(cam.K).float()[None]}
            if cam.depth is not None:
                view["depth"] = read_depth(cam.depth[t], cam.depth_scale, cam.size)[None]
            views.append(resize(view, self.size) if self.size else view)
        frame = {key: torch.cat([v[key] for v in views]) for key in views[0] if all(key in v for v in views)}
        cams = self.sequence.cameras
        if all(cam.poses is not None for cam in cams):
            frame["poses"] = torch.from_numpy(np.stack([cam.poses[t] for cam in cams]))
        if self.extrinsics is not None:
            frame["T_cam0_cam"] = self.extrinsics
        times = self.sequence.times
        frame["time"] = float(times[t]) if times is not None else float(t)
        frame["frame"] = t
        return frame
