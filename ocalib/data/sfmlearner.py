"""SfMLearner-prepared data (SfmLearner-Pytorch / SC-Depth format), loaded unchanged.

```
ROOT/train.txt, ROOT/val.txt      # scene folder names, one a line
ROOT/<scene>/*.jpg                # frames, already resized
ROOT/<scene>/cam.txt              # 3x3 K of those frames
ROOT/<scene>/poses.txt            # optional (--with-pose): KITTI format, camera-to-world
```

Convention: a scene is a one-camera sequence (camera ``cam0``).
"""

from __future__ import annotations

from pathlib import Path

from ocalib.data.folder import open_folder
from ocalib.data.sequence import Sequence
from ocalib.errors import InputError, read_text


def open_sfmlearner_scene(path: str | Path) -> Sequence:
    """Open one scene folder (holding ``cam.txt``)."""
    return open_folder(path, Path(path) / "cam.txt", layout="sfmlearner")


def read_split(path: str | Path) -> list[Path]:
    """A split file (``train.txt``) -> the scene folders it names, relative to its folder; each must exist."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: split file not found")
    scenes = []
    for lineno, line in enumerate(read_text(path, "split file").splitlines(), 1):
        if line.strip():
            scene = path.parent / line.strip()
            if not scene.is_dir():
                raise InputError(f"{path}:{lineno}: no folder {scene}")
            scenes.append(scene)
    if not scenes:
        raise InputError(f"{path}: the split names no scenes")
    return scenes
