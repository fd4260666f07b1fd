"""Pinhole intrinsics: updating K with every resize, crop and flip, and reading intrinsics files.

Convention: K (..., 3, 3) in pixels with integer pixel centres (kornia's convention). Resizing by a
factor s maps u -> (u + 0.5) s - 0.5 (``F.interpolate(align_corners=False)``), so fx' = s fx and
cx' = (cx + 0.5) s - 0.5; cropping at (x0, y0) subtracts the offset; a horizontal flip of an image W
pixels wide maps u -> W - 1 - u, so cx' = W - 1 - cx (fx stays positive: the flipped image is the view
of the mirrored world, see :func:`flip_pose`).
"""

from __future__ import annotations

import typing
from pathlib import Path

import numpy as np
import yaml

from ocalib.data.image_io import read_numbers
from ocalib.errors import InputError, read_text

if typing.TYPE_CHECKING:
    from torch import Tensor


def scale_intrinsics(K: Tensor, sx, sy) -> Tensor:
    """K (..., 3, 3) after resizing by ``sx`` horizontally and ``sy`` vertically (floats or (...) tensors)."""
    import torch  # here, as in the others: reading a sequence's intrinsics loads no torch

    K = K.clone()
    # python numbers stay numbers: a tensor made from one is a host-to-device copy on CUDA
    sx, sy = (
        s if isinstance(s, (int, float)) else torch.as_tensor(s, dtype=K.dtype, device=K.device) for s in (sx, sy)
    )
    K[..., 0, :] *= sx[..., None] if isinstance(sx, torch.Tensor) and sx.ndim else sx
    K[..., 1, :] *= sy[..., None] if isinstance(sy, torch.Tensor) and sy.ndim else sy
    K[..., 0, 2] += 0.5 * (sx - 1)  # (cx + 0.5) s - 0.5 = s cx + 0.5 (s - 1)
    K[..., 1, 2] += 0.5 * (sy - 1)
    return K


def resize_intrinsics(K: Tensor, old_size: tuple[int, int], new_size: tuple[int, int]) -> Tensor:
    """K (..., 3, 3) for an image resized from ``old_size`` (H, W) to ``new_size`` (H', W')."""
    return scale_intrinsics(K, new_size[1] / old_size[1], new_size[0] / old_size[0])


def crop_intrinsics(K: Tensor, x0, y0) -> Tensor:
    """K (..., 3, 3) for the crop whose top-left pixel is (x0, y0) (floats or (...) tensors)."""
    import torch

    K = K.clone()
    K[..., 0, 2] -= torch.as_tensor(x0, dtype=K.dtype, device=K.device)
    K[..., 1, 2] -= torch.as_tensor(y0, dtype=K.dtype, device=K.device)
    return K


def flip_intrinsics(K: Tensor, width: int) -> Tensor:
    """K (..., 3, 3) for the horizontally flipped image of ``width`` pixels: cx' = W - 1 - cx."""
    K = K.clone()
    K[..., 0, 2] = width - 1 - K[..., 0, 2]
    return K


def flip_pose(T: Tensor) -> Tensor:
    """A pose or relative pose (..., 4, 4) in the mirrored world of a horizontally flipped image: M T M,
    M = diag(-1, 1, 1, 1)."""
    import torch

    M = torch.diag(torch.tensor([-1.0, 1.0, 1.0, 1.0], dtype=T.dtype, device=T.device))
    return M @ T @ M


def intrinsics_from_projection(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A rectified projection matrix P = K [I | t] (3, 4) -> (K (3, 3), T_cam0_cam (4, 4)).

    Convention: t = K^-1 P[:, 3] maps reference-camera points into this camera (p_cam = p_cam0 + t), so
    this camera sits at -t in the reference frame (KITTI: P[0, 3] = -fx b puts camera 1 at x = +b).
    """
    K = np.array(P[:, :3], dtype=np.float64)
    T = np.eye(4)
    T[:3, 3] = -np.linalg.solve(K, P[:, 3])
    return K, T


def read_intrinsics(path: str | Path, size: tuple[int, int] | None = None) -> np.ndarray:
    """Read an intrinsics file -> K (3, 3) float64 at the image size ``size`` (H, W).

    * YAML (``.yaml``/``.yml``): ``K: [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` or ``fx, fy, cx, cy``;
      optional ``width, height``: the image size K belongs to, rescaled to ``size`` when they differ.
    * text: 9 numbers, a row-major 3x3 matrix (SfMLearner's ``cam.txt``).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: intrinsics file not found")
    if path.suffix.lower() not in (".yaml", ".yml"):
        values = read_numbers(path).ravel()
        if values.size != 9:
            raise InputError(f"{path}: expected 9 numbers (a 3x3 K), got {values.size}")
        return _checked(values.reshape(3, 3), path)
    try:
        data = yaml.safe_load(read_text(path, "intrinsics file"))
    except yaml.YAMLError as err:
        raise InputError(f"{path}: not valid YAML ({err})") from None
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a mapping with K or fx, fy, cx, cy")
    try:
        if "K" in data:
            K = np.asarray(data["K"], dtype=np.float64).reshape(3, 3)
        else:
            K = np.array([[data["fx"], 0, data["cx"]], [0, data["fy"], data["cy"]], [0, 0, 1]], dtype=np.float64)
    except (KeyError, TypeError, ValueError) as err:
        raise InputError(f"{path}: expected K (3x3) or fx, fy, cx, cy ({err!r})") from None
    K = _checked(K, path)
    if size is not None and "width" in data and "height" in data:
        old = (int(data["height"]), int(data["width"]))
        import torch

        K = resize_intrinsics(torch.from_numpy(K), old, size).numpy()
    return K


def _checked(K: np.ndarray, path: Path) -> np.ndarray:
    if not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0 or not np.allclose(K[2], [0, 0, 1]):
        raise InputError(f"{path}: not a pinhole K (need fx, fy > 0 and last row 0 0 1): {K.tolist()}")
    return K
