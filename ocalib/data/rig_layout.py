"""Loader of the project's native rig layout (what ``ocalib synth`` writes).

```
DIR/rig.yaml                      # cameras: name, width, height, K, optional T_cam0_cam, change, distortion; frame_rate
DIR/times.txt                     # optional: one time (s) a line; else frame / frame_rate
DIR/<name>/images/000000.png ...
DIR/<name>/depth/000000.png ...   # optional: uint16, metres x 256, 0 = no surface
DIR/<name>/poses.txt              # optional: KITTI, camera-to-world, one world frame
DIR/<name>/times.txt              # optional: the camera's own stamps (s or ns), where it is not triggered with the others
```

Every camera has its own ``times.txt`` or none does. With them, each camera holds its own number of images (gaps in
the numbering are dropped frames), one stamp an image, and ``DIR/times.txt`` is not read: the sequence's times are
camera 0's. Without them, every camera holds the same frames.

Convention: as :mod:`ocalib.data.rig` and :mod:`ocalib.data.sequence`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ocalib.data.image_io import list_frames
from ocalib.data.rig import read_rig_yaml
from ocalib.data.sequence import Camera, Sequence
from ocalib.errors import InputError
from ocalib.io.poses import read_kitti, read_times


def open_rig(path: str | Path) -> Sequence:
    """Open a native rig folder ``path`` (holding ``rig.yaml``)."""
    path = Path(path)
    rig = read_rig_yaml(path / "rig.yaml")
    stamped = _stamped(path, [spec.name for spec in rig.cameras])
    cameras = []
    for spec in rig.cameras:
        folder = path / spec.name
        images = list_frames(folder / "images", gaps=stamped)
        times = None
        if stamped:
            times = read_times(folder / "times.txt")
            if len(times) != len(images):
                raise InputError(f"{folder / 'times.txt'}: {len(times)} times for {len(images)} images")
        cameras.append(
            Camera(
                spec.name,
                images,
                spec.K,
                (spec.height, spec.width),
                spec.T_cam0_cam,
                change=spec.change,
                distortion=spec.distortion,
                times=times,
                time_offset=spec.time_offset,
            )
        )
    sequence = Sequence(path.name, path, "rig", cameras)  # checks the cameras' frame counts first
    for cam in cameras:
        if cam.change is not None and cam.change.frame >= len(cam):
            raise InputError(
                f"{path / 'rig.yaml'}: camera {cam.name}: change.frame {cam.change.frame} is past the last frame "
                f"({len(cam)} frames)"
            )
        folder = path / cam.name
        if (folder / "depth").is_dir():
            cam.depth = list_frames(folder / "depth", (".png",), gaps=stamped)
            if [p.stem for p in cam.depth] != [p.stem for p in cam.images]:
                raise InputError(
                    f"{folder / 'depth'}: depth frames do not match {folder / 'images'} "
                    f"({len(cam.depth)} vs {len(cam.images)} files)"
                )
        if (folder / "poses.txt").is_file():
            cam.poses = read_kitti(folder / "poses.txt")
            if len(cam.poses) != len(cam.images):
                raise InputError(f"{folder / 'poses.txt'}: {len(cam.poses)} poses for {len(cam.images)} images")
    times_file = path / "times.txt"
    if stamped:
        sequence.times = cameras[0].times
    elif times_file.exists():
        sequence.times = read_times(times_file)
        if len(sequence.times) != len(sequence):
            raise InputError(f"{times_file}: {len(sequence.times)} times for {len(sequence)} frames")
    else:
        sequence.times = np.arange(len(sequence)) / rig.frame_rate
    return sequence


def _stamped(path: Path, names: list[str]) -> bool:
    """Whether the cameras ``names`` of rig ``path`` have stamps of their own (``<name>/times.txt``): all or none,
    else an :class:`InputError` naming the first file missing (a folder of that name counts as there, to be refused
    when read)."""
    has = [(path / name / "times.txt").exists() for name in names]
    if all(has) or not any(has):
        return all(has)
    with_, without = names[has.index(True)], names[has.index(False)]
    raise InputError(
        f"{path / without / 'times.txt'}: missing, while {with_} has its own stamps: pairing frames in time needs "
        f"every camera's times.txt (or none: frame t of every camera is then one instant, stamped by "
        f"{path / 'times.txt'})"
    )
