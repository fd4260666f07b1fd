"""Lens distortion: OpenCV's two models, with OpenCV's names and coefficient order.

| model     | coeffs                  | OpenCV                                             |
|-----------|-------------------------|----------------------------------------------------|
| ``opencv``  | ``[k1, k2, p1, p2, k3]`` | ``cv2.projectPoints`` (radial and tangential)     |
| ``fisheye`` | ``[k1, k2, k3, k4]``     | ``cv2.fisheye.projectPoints`` (equidistant)       |

A camera without one is a pinhole (None). :func:`undistort_image` turns a distorted image into the pinhole image of
the same K and size (the front ends' view); its maps are computed once per camera and cached.

Convention: ``xy`` (N, 2) float64 are normalised image coordinates: a camera-frame point (x, y, z) is ``(x/z, y/z)``
before distortion and :func:`distort` of that after it; pixels are ``K @ [x, y, 1]`` with integer pixel centres
(ocalib's and OpenCV's convention alike).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ocalib.errors import InputError

MODELS = {"opencv": ("k1", "k2", "p1", "p2", "k3"), "fisheye": ("k1", "k2", "k3", "k4")}
NEWTON_STEPS = 30  # undistortion's Newton steps (a few suffice; the rest cost little and cover strong lenses)


@dataclass(frozen=True)
class Distortion:
    """One lens: ``model`` a key of :data:`MODELS`, ``coeffs`` in its order (floats)."""

    model: str
    coeffs: tuple[float, ...]

    def as_dict(self) -> dict:
        """As rig.yaml and a synth config write it: ``{model, coeffs}``."""
        return {"model": self.model, "coeffs": [float(c) for c in self.coeffs]}


def read_distortion(data, where: str) -> Distortion | None:
    """A ``distortion`` entry ``{model, coeffs}`` (or a :class:`Distortion`, or None) -> :class:`Distortion` or None;
    an :class:`InputError` naming ``where`` for an unknown model, a wrong number of coefficients or a non-number."""
    if data is None or isinstance(data, Distortion):
        return data
    if not isinstance(data, dict) or set(data) != {"model", "coeffs"}:
        got = f"keys {sorted(map(str, data))}" if isinstance(data, dict) else f"{data!r}"
        raise InputError(f"{where}: distortion must be a mapping with exactly model and coeffs, got {got}")
    model, coeffs = data["model"], data["coeffs"]
    if model not in MODELS:
        raise InputError(f"{where}: distortion: unknown model {model!r} (models: {', '.join(MODELS)})")
    names = MODELS[model]
    if not isinstance(coeffs, (list, tuple)) or len(coeffs) != len(names):
        raise InputError(
            f"{where}: distortion: model {model} needs {len(names)} coeffs [{', '.join(names)}], got {coeffs!r}"
        )
    if not all(isinstance(c, (int, float)) and not isinstance(c, bool) and math.isfinite(c) for c in coeffs):
        raise InputError(f"{where}: distortion: coeffs must be finite numbers, got {coeffs!r}")
    return Distortion(model, tuple(float(c) for c in coeffs))


def distort(xy: np.ndarray, distortion: Distortion) -> np.ndarray:
    """Undistorted normalised coordinates (..., 2) -> distorted ones (..., 2), as OpenCV's model computes them."""
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    if distortion.model == "fisheye":
        k1, k2, k3, k4 = distortion.coeffs
        r = np.sqrt(r2)
        theta = np.arctan(r)
        t2 = theta * theta
        theta_d = theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
        scale = np.where(r > 1e-12, theta_d / np.where(r > 1e-12, r, 1.0), 1.0)
        return xy * scale[..., None]
    k1, k2, p1, p2, k3 = distortion.coeffs
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([xd, yd], -1)


def undistort(xy_d: np.ndarray, distortion: Distortion, tolerance: float = 1e-10) -> np.ndarray:
    """Distorted normalised coordinates (N, 2) -> undistorted ones (N, 2): Newton's method on :func:`distort`
    (numerical Jacobian), from the distorted point. NaN where it does not converge to ``tolerance`` (a lens not
    invertible there, e.g. a strong radial term folding back)."""
    xy_d = np.asarray(xy_d, dtype=np.float64)
    xy, h = xy_d.copy(), 1e-7
    for _ in range(NEWTON_STEPS):
        residual = distort(xy, distortion) - xy_d
        if not np.abs(residual).max(initial=0.0) >= tolerance:  # converged (or NaN: not invertible)
            break
        dx = (distort(xy + [h, 0], distortion) - distort(xy - [h, 0], distortion)) / (2 * h)  # (N, 2) d/dx
        dy = (distort(xy + [0, h], distortion) - distort(xy - [0, h], distortion)) / (2 * h)
        det = dx[:, 0] * dy[:, 1] - dy[:, 0] * dx[:, 1]
        step_x = (dy[:, 1] * residual[:, 0] - dy[:, 0] * residual[:, 1]) / det
        step_y = (dx[:, 0] * residual[:, 1] - dx[:, 1] * residual[:, 0]) / det
        xy = xy - np.stack([step_x, step_y], -1)
    converged = np.abs(distort(xy, distortion) - xy_d).max(-1) < tolerance
    return np.where(converged[:, None], xy, np.nan)


def project(points: np.ndarray, K: np.ndarray, distortion: Distortion | None) -> np.ndarray:
    """Camera-frame points (N, 3) (z > 0) -> pixels (N, 2) through the lens and K (3, 3)."""
    xy = points[:, :2] / points[:, 2:]
    if distortion is not None:
        xy = distort(xy, distortion)
    return xy @ K[:2, :2].T + K[:2, 2]


def undistort_pixels(pixels: np.ndarray, K: np.ndarray, distortion: Distortion | None) -> np.ndarray:
    """Distorted pixels (N, 2) -> the pinhole pixels (N, 2) of the same rays under the same K (NaN where the lens is
    not invertible)."""
    xy = (pixels - K[:2, 2]) @ np.linalg.inv(K[:2, :2]).T
    if distortion is not None:
        xy = undistort(xy, distortion)
    return xy @ K[:2, :2].T + K[:2, 2]


def invertible(K: np.ndarray, size: tuple[int, int], distortion: Distortion) -> bool:
    """Whether every ray of an image of ``size`` (H, W) through K (3, 3) and the lens is found by :func:`undistort`:
    checked on the image's outer edge (pixel centres +-0.5, every half pixel), where a radial lens first folds back
    (or, a fisheye, passes 90 deg)."""
    height, width = size
    u, v = np.arange(-0.5, width, 0.5), np.arange(-0.5, height, 0.5)
    edge = np.concatenate(
        [np.stack([u, np.full_like(u, v[0])], 1), np.stack([u, np.full_like(u, v[-1])], 1)]
        + [np.stack([np.full_like(v, u[0]), v], 1), np.stack([np.full_like(v, u[-1]), v], 1)]
    )
    return bool(np.isfinite(undistort_pixels(edge, K, distortion)).all())


def undistort_image(image: np.ndarray, K: np.ndarray, distortion: Distortion) -> np.ndarray:
    """A distorted image (H, W[, 3]) -> the pinhole image of the same K and size (bilinear; black where the
    distorted image does not reach)."""
    import cv2

    map_x, map_y = undistort_maps(K, image.shape[:2], distortion)
    return cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)


def undistort_maps(K: np.ndarray, size: tuple[int, int], distortion: Distortion) -> tuple[np.ndarray, np.ndarray]:
    """``cv2.remap``'s maps (H, W) float32 of :func:`undistort_image` for K (3, 3) and size (H, W), keeping K (OpenCV's
    ``initUndistortRectifyMap``, ``fisheye.initUndistortRectifyMap`` for the fisheye); cached per camera."""
    return _maps(tuple(np.asarray(K, dtype=np.float64).ravel()), tuple(size), distortion)


@lru_cache(maxsize=64)
def _maps(K: tuple, size: tuple[int, int], distortion: Distortion) -> tuple[np.ndarray, np.ndarray]:
    import cv2

    K = np.array(K).reshape(3, 3)
    D, (height, width) = np.array(distortion.coeffs), size
    if distortion.model == "fisheye":
        maps = cv2.fisheye.initUndistortRectifyMap(K, D, np.eye(3), K, (width, height), cv2.CV_32FC1)
    else:
        maps = cv2.initUndistortRectifyMap(K, D, None, K, (width, height), cv2.CV_32FC1)
    for m in maps:
        m.setflags(write=False)
    return maps
