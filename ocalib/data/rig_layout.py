"""Loader of the project's native rig layout (what ``ocalib synth`` writes).

```
DIR/rig.yaml                      # cameras: name, width, height, K, optional T_cam0_cam, change, distortion; frame_rate
DIR/times.txt                     # optional: one time (s) a line; else frame / frame_rate
DIR/<name>/images/000000.png ...
DIR/<name>/depth/000000.png ...   # optional: uint16, metres x 256, 0 = no surface
DIR/<name>/poses.txt              # optional: KITTI, camera-to-world, one world frame
DIR/<name>/times.txt              # optional: the camera's own stamps (s), where it is not triggered with the others
```

Convention: as :mod:`ocalib.data.rig` and :mod:`ocalib.data.sequence`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ocalib.data.image_io import list_frames, read_numbers
from ocalib.data.rig import read_rig_yaml
from ocalib.data.sequence import Camera, Sequence
from ocalib.errors import InputError
from ocalib.io.poses import read_kitti
from ocalib.io.timing import increasing


def open_rig(path: str | Path) -> Sequence:
    """Open a native rig folder ``path`` (holding ``rig.yaml``)."""
    path = Path(path)
    rig = read_rig_yaml(path / "rig.yaml")
    cameras = []
    for spec in rig.cameras:
        images = list_frames(path / spec.name / "images")
        cameras.append(
            Camera(
                spec.name,
                images,
                spec.K,
                (spec.height, spec.width),
                spec.T_cam0_cam,
                change=spec.change,
                distortion=spec.distortion,
                time_offset=spec.time_offset,
            )
        )
    sequence = Sequence(path.name, path, "rig", cameras)  # checks the cameras' frame counts first
    for cam in cameras:
        if cam.change is not None and cam.change.frame >= len(sequence):
            raise InputError(
                f"{path / 'rig.yaml'}: camera {cam.name}: change.frame {cam.change.frame} is past the last frame "
                f"({len(sequence)} frames)"
            )
        folder = path / cam.name
        if (folder / "depth").is_dir():
            cam.depth = list_frames(folder / "depth", (".png",))
            if [p.stem for p in cam.depth] != [p.stem for p in cam.images]:
                raise InputError(
                    f"{folder / 'depth'}: depth frames do not match {folder / 'images'} "
                    f"({len(cam.depth)} vs {len(cam.images)} files)"
                )
        if (folder / "times.txt").is_file():
            cam.times = increasing(read_numbers(folder / "times.txt", 1)[:, 0], str(folder / "times.txt"))
            if len(cam.times) != len(cam.images):
                raise InputError(f"{folder / 'times.txt'}: {len(cam.times)} times for {len(cam.images)} images")
        if (folder / "poses.txt").is_file():
            cam.poses = read_kitti(folder / "poses.txt")
            if len(cam.poses) != len(cam.images):
                raise InputError(f"{folder / 'poses.txt'}: {len(cam.poses)} poses for {len(cam.images)} images")
    times_file = path / "times.txt"
    if times_file.is_file():
        sequence.times = read_numbers(times_file, 1)[:, 0]
        if len(sequence.times) != len(sequence):
            raise InputError(f"{times_file}: {len(sequence.times)} times for {len(sequence)} frames")
    else:
        sequence.times = np.arange(len(sequence)) / rig.frame_rate
    return sequence
