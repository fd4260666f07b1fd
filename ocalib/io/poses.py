"""Pose files.

Convention: every pose is camera-to-world, a 4x4 float64 matrix.

* KITTI: one pose a line, 12 numbers, the row-major top 3x4 of the matrix.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ocalib.errors import InputError


def read_kitti(path: str | Path) -> np.ndarray:
    """Read a KITTI pose file -> (N, 4, 4) float64. Errors name the file and line."""
    path = Path(path)
    rows = []
    for lineno, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        try:
            values = [float(v) for v in line.replace(",", " ").split()]
        except ValueError:
            raise InputError(f"{path}:{lineno}: not a number in {line.strip()[:60]!r}") from None
        if len(values) != 12:
            raise InputError(f"{path}:{lineno}: expected 12 numbers (a row-major 3x4 pose), got {len(values)}")
        rows.append(values)
    if not rows:
        raise InputError(f"{path}: no poses in the file")
    poses = np.zeros((len(rows), 4, 4))
    poses[:, :3, :] = np.asarray(rows).reshape(-1, 3, 4)
    poses[:, 3, 3] = 1
    return poses


def write_kitti(path: str | Path, poses) -> None:
    """Write poses (N, 4, 4) (numpy or torch) as a KITTI pose file."""
    poses = np.asarray(poses.detach().cpu() if hasattr(poses, "detach") else poses, dtype=np.float64)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, poses[:, :3, :].reshape(-1, 12), fmt="%.9e")
