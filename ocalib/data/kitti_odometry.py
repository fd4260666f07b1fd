"""Loader of a KITTI odometry sequence (``dataset/sequences/XX``).

```
sequences/XX/image_0..3/000000.png   # 0, 1: grey left/right; 2, 3: colour left/right (all rectified)
sequences/XX/calib.txt               # P0..P3: 3x4 projection matrices (Tr: velodyne, unused)
sequences/XX/times.txt               # one time (s) a line
poses/XX.txt                         # optional (00-10): camera 0's pose, KITTI format
```

Convention: the first camera present (``image_0``) is the reference; camera i is translated from it by P_i = K_i [I | t_i]
(P_i[0, 3] = -fx b_i). Ground truth is camera 0's camera-to-world pose (world = its first frame); camera
i's pose is that times T_cam0_cami.
"""

from __future__ import annotations

from pathlib import Path

from ocalib.data.image_io import image_size, list_frames, read_numbers
from ocalib.data.intrinsics import intrinsics_from_projection
from ocalib.data.kitti_raw import calib_matrix, read_calib_file
from ocalib.data.sequence import Camera, Sequence
from ocalib.errors import InputError
from ocalib.io.poses import read_kitti


def open_kitti_odometry(path: str | Path) -> Sequence:
    """Open a KITTI odometry sequence folder ``path`` (holding ``calib.txt`` and ``image_0``..``image_3``)."""
    path = Path(path)
    calib_file = path / "calib.txt"
    calib = read_calib_file(calib_file)
    folders = [path / f"image_{i}" for i in range(4) if (path / f"image_{i}").is_dir()]
    if not folders:
        raise InputError(f"{path}: no image_0..image_3 folders")
    cameras = []
    for folder in folders:
        K, T_cam0_cam = intrinsics_from_projection(calib_matrix(calib_file, calib, f"P{folder.name[-1]}", (3, 4)))
        images = list_frames(folder)
        cameras.append(Camera(folder.name, images, K, image_size(images[0]), T_cam0_cam))
    sequence = Sequence(path.name, path, "kitti_odometry", cameras)

    times_file = path / "times.txt"
    if times_file.is_file():
        sequence.times = read_numbers(times_file, 1)[:, 0]
        if len(sequence.times) != len(sequence):
            raise InputError(f"{times_file}: {len(sequence.times)} times for {len(sequence)} frames")
    pose_file = path.parent.parent / "poses" / f"{path.name}.txt"
    if pose_file.is_file():
        poses = read_kitti(pose_file)
        if len(poses) != len(sequence):
            raise InputError(f"{pose_file}: {len(poses)} poses for {len(sequence)} frames")
        for cam in cameras:
            cam.poses = poses @ cam.T_cam0_cam
    return sequence.select(sequence.names)  # extrinsics relative to the first camera present
