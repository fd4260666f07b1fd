"""Training snippets: a target frame and source frames at fixed offsets, from every camera of the sequences.

A sample is a dict:

* ``image`` (S, 3, H, W) float32 in [0, 1]: the target first, then the sources in the order of ``offsets``;
* ``K`` (3, 3) float32 at the output size;
* ``depth`` (S, 1, H, W) float32 metres (0 = no surface), when the layout has depth;
* ``poses`` (S, 4, 4) float32, when the layout has ground truth: frame s's pose in the target camera's
  frame, ``T_target^-1 T_s`` (``poses[0]`` is the identity);
* ``sequence`` (str), ``camera`` (str), ``frame`` (int): where the target comes from.

Convention: camera-to-world poses; K with integer pixel centres, scaled with every resize.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
from torch.utils.data import Dataset, default_collate

from ocalib.data.frame_cache import FrameCache
from ocalib.data.image_io import decode_depth, decode_image, depth_tensor, image_tensor
from ocalib.data.intrinsics import resize_intrinsics
from ocalib.data.sequence import Sequence
from ocalib.data.static import snippet_motion, thumbnails
from ocalib.errors import InputError


class SnippetDataset(Dataset):
    """Snippets of every camera of ``sequences`` whose frames are all inside the sequence.

    ``size`` (H, W): output resolution (None keeps each camera's own). ``static_threshold`` > 0 drops
    snippets whose motion (:func:`ocalib.data.static.snippet_motion`) is below it. ``transform`` maps a
    sample to a sample (e.g. :class:`ocalib.data.augment.SnippetAugmentation`). ``cache_mb``: decoded frames
    (at the output size) kept in memory, per process (:class:`ocalib.data.frame_cache.FrameCache`; 0: none).
    """

    def __init__(
        self,
        sequences: list[Sequence],
        offsets=(-1, 1),
        size: tuple[int, int] | None = None,
        static_threshold: float = 0.0,
        transform: Callable[[dict], dict] | None = None,
        cache_mb: float = 0.0,
    ):
        self.offsets = [int(o) for o in offsets]
        if not self.offsets or 0 in self.offsets:
            raise InputError(f"snippet offsets must be non-empty and non-zero, got {self.offsets}")
        self.sequences, self.size, self.transform = sequences, size, transform
        self.cache = FrameCache(int(cache_mb * 2**20))
        self.items = []  # (sequence index, camera index, target frame)
        first, last = max(0, -min(self.offsets)), max(0, max(self.offsets))
        for si, seq in enumerate(sequences):
            targets = list(range(first, len(seq) - last))
            for ci, cam in enumerate(seq.cameras):
                keep = targets
                if static_threshold > 0 and targets:
                    motion = snippet_motion(thumbnails(cam.images), targets, self.offsets)
                    keep = [t for t, m in zip(targets, motion.tolist()) if m >= static_threshold]
                self.items += [(si, ci, t) for t in keep]

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, index: int) -> dict:
        si, ci, t = self.items[index]
        seq = self.sequences[si]
        cam = seq.cameras[ci]
        frames = [t] + [t + o for o in self.offsets]
        size = tuple(self.size or cam.size)
        sample = {
            "image": torch.stack(
                [image_tensor(self._decoded(decode_image, cam.images[f], cam.size, size)) for f in frames]
            ),
            "K": resize_intrinsics(torch.from_numpy(cam.K), cam.size, size).float(),
            "sequence": seq.name,
            "camera": cam.name,
            "frame": t,
        }
        if cam.depth is not None:
            sample["depth"] = torch.stack(
                [
                    depth_tensor(self._decoded(decode_depth, cam.depth[f], cam.size, size), cam.depth_scale)
                    for f in frames
                ]
            )
        if cam.poses is not None:
            poses = np.linalg.inv(cam.poses[t]) @ cam.poses[frames]
            sample["poses"] = torch.from_numpy(poses).float()
        return self.transform(sample) if self.transform else sample

    def _decoded(self, decode, path, camera_size, size):
        return self.cache((str(path), size), lambda: decode(path, camera_size, size))


def collate_snippets(samples: list[dict]) -> dict:
    """Batch samples, keeping only the keys all of them have (sequences of different layouts mix)."""
    keys = set.intersection(*(set(s) for s in samples))
    return default_collate([{k: s[k] for k in keys} for s in samples])
