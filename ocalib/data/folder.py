"""Loader of a plain folder of images with an intrinsics file: a single camera, e.g. the user's own video.

```
DIR/*.png|*.jpg ...          # frames in natural name order (numbered names must be consecutive)
DIR/intrinsics.yaml          # or intrinsics.yml, K.txt, cam.txt, intrinsics.txt (see read_intrinsics)
DIR/poses.txt                # optional: KITTI format, camera-to-world ground truth
DIR/times.txt                # optional: one time (s) a line
```

Convention: K is given at the images' size (or declares its own width/height and is rescaled).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ocalib.data.image_io import image_size, list_frames, read_numbers
from ocalib.data.intrinsics import read_intrinsics
from ocalib.data.sequence import Camera, Sequence
from ocalib.errors import InputError
from ocalib.io.poses import read_kitti

INTRINSICS_NAMES = ("intrinsics.yaml", "intrinsics.yml", "K.txt", "cam.txt", "intrinsics.txt")


def find_intrinsics(path: Path) -> Path | None:
    """The first of :data:`INTRINSICS_NAMES` present in folder ``path``."""
    return next((path / n for n in INTRINSICS_NAMES if (path / n).is_file()), None)


def open_folder(path: str | Path, intrinsics: str | Path | None = None, layout: str = "folder") -> Sequence:
    """Open an image folder as a one-camera sequence (camera ``cam0``); ``intrinsics`` overrides the file search."""
    path = Path(path)
    images = list_frames(path)
    K_file = Path(intrinsics) if intrinsics is not None else find_intrinsics(path)
    if K_file is None:
        raise InputError(f"{path}: no intrinsics file ({', '.join(INTRINSICS_NAMES)}); pass one explicitly")
    size = image_size(images[0])
    poses = read_kitti(path / "poses.txt") if (path / "poses.txt").is_file() else None
    if poses is not None and len(poses) != len(images):
        raise InputError(f"{path / 'poses.txt'}: {len(poses)} poses for {len(images)} images")
    camera = Camera("cam0", images, read_intrinsics(K_file, size), size, np.eye(4), poses)
    sequence = Sequence(path.name, path, layout, [camera])
    if (path / "times.txt").is_file():
        sequence.times = read_numbers(path / "times.txt", 1)[:, 0]
        if len(sequence.times) != len(sequence):
            raise InputError(f"{path / 'times.txt'}: {len(sequence.times)} times for {len(sequence)} frames")
    return sequence
