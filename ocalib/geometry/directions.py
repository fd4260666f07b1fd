"""Directions in 3-D, numpy (no torch): the angle between two vectors, the projector that leaves some directions
out, the axes that directions touch, a difference's component along an axis."""

from __future__ import annotations

import math

import numpy as np

UNOBSERVABLE_AXIS_SHARE = 0.1  # an axis with this share of an unobservable direction has no std (a car's y, not x)


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle between two vectors (3,) in degrees (NaN when either is zero)."""
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    if na == 0 or nb == 0:
        return math.nan
    return math.degrees(math.atan2(np.linalg.norm(np.cross(a, b)), float(a @ b)))


def projector_without(directions: np.ndarray) -> np.ndarray:
    """(3, 3) the orthogonal projector onto what ``directions`` (n, 3) (unit rows; NaN rows ignored) leave: rows
    within about 15 deg of each other count as one direction (a car's height, unobservable and the ground's normal)."""
    rows = np.asarray(directions, np.float64).reshape(-1, 3)
    rows = rows[np.isfinite(rows).all(1)]
    if not len(rows):
        return np.eye(3)
    _, s, vt = np.linalg.svd(rows)
    basis = vt[: int(np.sum(s > 0.2))]
    return np.eye(3) - basis.T @ basis


def touched_axes(directions: np.ndarray, share: float = UNOBSERVABLE_AXIS_SHARE) -> np.ndarray:
    """(3,) bool: the axes that any of the unit ``directions`` (n, 3) has a share over ``share`` of (none for n = 0);
    with unobservable translation directions, the axes whose 1-sigma is not a measurement."""
    return (np.abs(np.asarray(directions, dtype=float).reshape(-1, 3)) > share).any(0)


def height_error(t: np.ndarray, t_true: np.ndarray, axis: np.ndarray) -> float | None:
    """The error of translation ``t`` (3,) against ``t_true`` along the ground's normal ``axis`` (3,) (a car's
    camera height: outside the targets compared in the ground plane); None where ``axis`` is NaN (not planar)."""
    return float(abs(axis @ (t - t_true))) if np.isfinite(axis).all() else None
