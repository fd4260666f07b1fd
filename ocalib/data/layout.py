"""One entry point for every layout: detect it from the folder, open it as a :class:`Sequence`.

| layout           | recognised by                                   |
|------------------|-------------------------------------------------|
| ``rig``          | ``rig.yaml``                                    |
| ``kitti_raw``    | ``image_0x/data`` folders                       |
| ``kitti_odometry`` | ``calib.txt`` and ``image_0``..``image_3``    |
| ``sfmlearner``   | ``cam.txt`` beside the images                   |
| ``folder``       | images and an intrinsics file                   |

Convention: as :mod:`ocalib.data.sequence` (camera-to-world poses, extrinsics relative to the first camera).
"""

from __future__ import annotations

from pathlib import Path

from ocalib.data.folder import find_intrinsics, open_folder
from ocalib.data.image_io import IMAGE_SUFFIXES
from ocalib.data.kitti_odometry import open_kitti_odometry
from ocalib.data.kitti_raw import open_kitti_raw
from ocalib.data.rig_layout import open_rig
from ocalib.data.sequence import Sequence
from ocalib.data.sfmlearner import open_sfmlearner_scene, read_split
from ocalib.errors import InputError

LAYOUTS = ("rig", "kitti_raw", "kitti_odometry", "sfmlearner", "folder")


def detect_layout(path: str | Path) -> str | None:
    """The layout of folder ``path``, or None when it is none of :data:`LAYOUTS`."""
    path = Path(path)
    if not path.is_dir():
        return None
    if (path / "rig.yaml").is_file():
        return "rig"
    if any((path / f"image_0{i}" / "data").is_dir() for i in range(4)):
        return "kitti_raw"
    if (path / "calib.txt").is_file() and any((path / f"image_{i}").is_dir() for i in range(4)):
        return "kitti_odometry"
    if (path / "cam.txt").is_file():
        return "sfmlearner"
    if find_intrinsics(path) and _has_images(path):
        return "folder"
    return None


def _has_images(path: Path) -> bool:
    return path.is_dir() and any(p.suffix.lower() in IMAGE_SUFFIXES for p in path.iterdir())


def open_sequence(path: str | Path, cameras: list[str] | None = None, intrinsics: str | Path | None = None) -> Sequence:
    """Open the sequence at ``path`` whatever its layout.

    ``cameras``: names to keep, in order (the first becomes the extrinsics reference); None keeps all.
    ``intrinsics``: the intrinsics file of a plain image folder (else one is searched for beside the images);
    other layouts carry their own and ignore it.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file or folder")
    layout = detect_layout(path)
    if layout is None and intrinsics is not None and path.is_dir():
        layout = "folder"
    if layout is None:
        if path.is_dir() and not any(path.iterdir()):
            raise InputError(f"{path}: the folder is empty")
        cameras = path.is_dir() and any(_holds_images(p) or _holds_images(p / "images") for p in path.iterdir())
        raise InputError(
            f"{path}: not a sequence folder of a known layout ({', '.join(LAYOUTS)}); "
            + (
                f"a rig (a folder of images per camera) needs {path / 'rig.yaml'} with each camera's K and size "
                "(docs/guide.md: from images)"
                if cameras
                else "a plain image folder needs an intrinsics file (intrinsics.yaml, K.txt, cam.txt)"
            )
        )
    if layout == "folder":
        sequence = open_folder(path, intrinsics)
    else:
        sequence = {
            "rig": open_rig,
            "kitti_raw": open_kitti_raw,
            "kitti_odometry": open_kitti_odometry,
            "sfmlearner": open_sfmlearner_scene,
        }[layout](path)
    return sequence.select(cameras)


def find_sequences(path: str | Path) -> list[Path]:
    """Expand ``path`` to sequence folders, sorted: a sequence (or a folder of images) itself; a split file (``train.txt``) naming
    scene folders; a KITTI odometry ``dataset`` (its ``sequences/XX``); or a folder of sequences (a KITTI
    date folder, an SfMLearner root, a folder of rigs)."""
    path = Path(path)
    if path.is_file() and path.suffix == ".txt":
        return read_split(path)
    if detect_layout(path) or _has_images(path):
        return [path]
    if (path / "sequences").is_dir():
        path = path / "sequences"
    found = sorted(p for p in path.iterdir() if detect_layout(p)) if path.is_dir() else []
    if not found:
        raise InputError(f"{path}: no sequences found (no folder of a known layout: {', '.join(LAYOUTS)})")
    return found


def _holds_images(folder: Path) -> bool:
    """Whether ``folder`` is a folder with image files in it."""
    return folder.is_dir() and any(f.suffix.lower() in IMAGE_SUFFIXES for f in folder.iterdir())
