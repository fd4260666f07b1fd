"""Write the native rig layout.

```
DIR/rig.yaml                      # ocalib.data.rig.write_rig_yaml
DIR/times.txt                     # one timestamp (s) a line
DIR/<name>/times.txt              # where a camera has a clock of its own (a time_offset): its own stamps
DIR/<name>/images/000000.png ...  # 8-bit RGB
DIR/<name>/depth/000000.png ...   # uint16, metres x 256, 0 = no surface
DIR/<name>/poses.txt              # KITTI, camera-to-world, one world frame
```
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from torch import Tensor

from ocalib.data.rig import RigSpec, write_rig_yaml
from ocalib.io.poses import write_kitti

DEPTH_SCALE = 256.0


def to_rgb8(image: Tensor) -> np.ndarray:
    """(3, H, W) in [0, 1] -> (H, W, 3) uint8 RGB (rounded)."""
    return (image.detach().clamp(0, 1) * 255).round().byte().permute(1, 2, 0).cpu().numpy()


def to_depth16(depth: Tensor) -> np.ndarray:
    """(H, W) metres -> (H, W) uint16 metres x 256 (0 stays 0 = no surface; clipped at 255.99 m)."""
    return (depth.detach().cpu().double() * DEPTH_SCALE).round().clamp(0, 65535).numpy().astype(np.uint16)


def write_frame(out: Path, camera: str, index: int, image: Tensor, depth: Tensor) -> None:
    """Write one camera's image (3, H, W) and depth (H, W) for frame ``index``."""
    name = f"{index:06d}.png"
    cv2.imwrite(str(out / camera / "images" / name), cv2.cvtColor(to_rgb8(image), cv2.COLOR_RGB2BGR))
    cv2.imwrite(str(out / camera / "depth" / name), to_depth16(depth))


def write_header(out: Path, rig: RigSpec, times: np.ndarray, poses: np.ndarray) -> None:
    """Create the folders and write rig.yaml, times.txt and each camera's poses (K, N, 4, 4); where the cameras
    have clocks of their own (a ``time_offset``), each camera's stamps ``times`` on its clock too."""
    out.mkdir(parents=True, exist_ok=True)
    write_rig_yaml(out / "rig.yaml", rig)
    np.savetxt(out / "times.txt", times, fmt="%.6f")
    for cam, p in zip(rig.cameras, poses):
        (out / cam.name / "images").mkdir(parents=True, exist_ok=True)
        (out / cam.name / "depth").mkdir(parents=True, exist_ok=True)
        write_kitti(out / cam.name / "poses.txt", p)
        if cam.time_offset is not None:
            np.savetxt(out / cam.name / "times.txt", times, fmt="%.6f")
