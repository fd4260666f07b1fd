"""Reading images, depth maps and numbered frame folders (cv2, ``IMREAD_UNCHANGED``).

Convention: images are float32 tensors (3, H, W) in [0, 1], RGB; grey images are expanded to 3 channels.
Depth maps are float32 (1, H, W) in metres, 0 where there is no surface.
"""

from __future__ import annotations

import re
import typing
from pathlib import Path

import cv2
import numpy as np

from ocalib.errors import InputError, read_text

if typing.TYPE_CHECKING:
    from torch import Tensor

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".ppm", ".pgm", ".tif", ".tiff")
_PIXEL_SCALE = {np.uint8: 255.0, np.uint16: 65535.0}  # full scale of the pixel types read


def _imread(path: Path) -> np.ndarray:
    array = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if array is None:
        raise InputError(f"{path}: cannot read the image (missing, unreadable or corrupt)")
    return array


def read_image(
    path: str | Path, size: tuple[int, int] | None = None, out_size: tuple[int, int] | None = None
) -> Tensor:
    """Read an image -> (3, H, W) float32 in [0, 1]. ``size`` (H, W), if given, must match the file;
    ``out_size`` (H', W') resizes it (cv2: area when shrinking, else bilinear; pixel centres map as
    u -> (u + 0.5) s - 0.5, see :func:`ocalib.data.intrinsics.resize_intrinsics`)."""
    return image_tensor(decode_image(path, size, out_size))


def decode_image(
    path: str | Path, size: tuple[int, int] | None = None, out_size: tuple[int, int] | None = None
) -> np.ndarray:
    """:func:`read_image` before the conversion: (H, W, 3) RGB or (H, W) grey, uint8 or uint16."""
    path = Path(path)
    array = _checked_size(_imread(path), size, path, "image")
    if array.dtype.type not in _PIXEL_SCALE:
        raise InputError(f"{path}: unsupported pixel type {array.dtype} (expected 8 or 16 bit)")
    if array.ndim == 3:  # BGR(A) -> RGB; grey + alpha -> grey
        array = cv2.cvtColor(array[:, :, :3], cv2.COLOR_BGR2RGB) if array.shape[2] >= 3 else array[:, :, 0]
    return resize_image(array, out_size)


def resize_image(array: np.ndarray, out_size: tuple[int, int] | None) -> np.ndarray:
    """A decoded image (H, W[, 3]) resized to ``out_size`` (H', W') as :func:`read_image` does; None keeps it."""
    if out_size is None or tuple(out_size) == array.shape[:2]:
        return array
    shrink = out_size[0] <= array.shape[0] and out_size[1] <= array.shape[1]
    return cv2.resize(array, (out_size[1], out_size[0]), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)


def image_tensor(array: np.ndarray) -> Tensor:
    """A decoded image (:func:`decode_image`) -> (3, H, W) float32 in [0, 1] (grey expanded to 3 channels)."""
    import torch  # here: listing and reading images loads no torch

    image = torch.from_numpy(array.astype(np.float32) / _PIXEL_SCALE[array.dtype.type])
    return image.permute(2, 0, 1).contiguous() if image.ndim == 3 else image.expand(3, -1, -1).contiguous()


def grey_image(array: np.ndarray) -> np.ndarray:
    """A decoded image (:func:`decode_image`) -> (H, W) uint8 grey: 16-bit scaled to 8 as :func:`image_tensor`'s
    [0, 1] times 255, rounded half to even; colour by OpenCV's RGB -> grey weights. The same pixels as
    :func:`image_tensor`'s, converted so, without the float copy."""
    if array.dtype != np.uint8:
        scale = np.float32(_PIXEL_SCALE[array.dtype.type])
        array = np.round(array.astype(np.float32) / scale * np.float32(255.0)).astype(np.uint8)
    return cv2.cvtColor(array, cv2.COLOR_RGB2GRAY) if array.ndim == 3 else array


def read_depth(
    path: str | Path, scale: float = 256.0, size: tuple[int, int] | None = None, out_size: tuple[int, int] | None = None
) -> Tensor:
    """Read a uint16 depth PNG (metres x ``scale``, 0 = no surface) -> (1, H, W) float32 metres; ``size`` and
    ``out_size`` as :func:`read_image`, resizing by nearest neighbour (``INTER_NEAREST_EXACT``)."""
    return depth_tensor(decode_depth(path, size, out_size), scale)


def decode_depth(
    path: str | Path, size: tuple[int, int] | None = None, out_size: tuple[int, int] | None = None
) -> np.ndarray:
    """:func:`read_depth` before the conversion: (H, W) uint16."""
    path = Path(path)
    array = _checked_size(_imread(path), size, path, "depth")
    if array.dtype != np.uint16 or array.ndim != 2:
        raise InputError(f"{path}: depth must be a single-channel uint16 image, got {array.dtype} {array.shape}")
    if out_size is not None and tuple(out_size) != array.shape:
        array = cv2.resize(array, (out_size[1], out_size[0]), interpolation=cv2.INTER_NEAREST_EXACT)
    return array


def depth_tensor(array: np.ndarray, scale: float = 256.0) -> Tensor:
    """A decoded depth map (:func:`decode_depth`) -> (1, H, W) float32 metres."""
    import torch

    return torch.from_numpy(array.astype(np.float32) / scale)[None]


def _checked_size(array: np.ndarray, size, path: Path, what: str) -> np.ndarray:
    if size is not None and array.shape[:2] != tuple(size):
        raise InputError(f"{path}: {what} is {array.shape[0]}x{array.shape[1]} (HxW), expected {size[0]}x{size[1]}")
    return array


def image_size(path: str | Path) -> tuple[int, int]:
    """(H, W) of an image file."""
    return tuple(_imread(Path(path)).shape[:2])


def _natural_key(path: Path):
    return [int(s) if s.isdigit() else s for s in re.split(r"(\d+)", path.name)]


def list_frames(folder: str | Path, suffixes=IMAGE_SUFFIXES, gaps: bool = False) -> list[Path]:
    """The image files of a folder in frame order.

    When every name is a number (``000000.png``) the numbers must be consecutive unless ``gaps`` (a camera with
    stamps of its own, that drops frames): a gap is an :class:`InputError` naming the missing file. Other names are
    sorted naturally (``img2`` < ``img10``).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: no such folder")
    files = sorted((p for p in folder.iterdir() if p.suffix.lower() in suffixes and p.is_file()), key=_natural_key)
    if not files:
        raise InputError(f"{folder}: no images ({', '.join(suffixes[:3])}, ...) in the folder")
    if all(p.stem.isdigit() for p in files):
        numbers = [int(p.stem) for p in files]
        for prev, path, number in zip(files, files[1:], numbers[1:]):
            if number == int(prev.stem):
                raise InputError(f"{path}: frame {prev.stem} is there twice ({prev.name}, {path.name})")
            if number != int(prev.stem) + 1 and not gaps:
                missing = str(int(prev.stem) + 1).zfill(len(prev.stem)) + prev.suffix
                raise InputError(f"{folder / missing}: frame is missing (the folder has {prev.name}, then {path.name})")
    return files


def read_numbers(path: str | Path, columns: int | None = None) -> np.ndarray:
    """A text file of numbers, one row a line (blank and ``#`` lines skipped) -> (N, columns) float64."""
    path = Path(path)
    rows = []
    for lineno, line in enumerate(read_text(path).splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        try:
            row = [float(v) for v in line.replace(",", " ").split()]
        except ValueError:
            raise InputError(f"{path}:{lineno}: not a number in {line.strip()[:60]!r}") from None
        if columns is not None and len(row) != columns:
            raise InputError(f"{path}:{lineno}: expected {columns} numbers, got {len(row)}")
        rows.append(row)
    if not rows:
        raise InputError(f"{path}: the file holds no numbers")
    if len({len(r) for r in rows}) != 1:
        raise InputError(f"{path}: rows have different numbers of values")
    return np.asarray(rows, dtype=np.float64)
