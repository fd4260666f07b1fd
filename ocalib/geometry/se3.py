"""Rigid motions in numpy (float64, no torch): SO(3)'s exp and log, rotation angles, inverse and chained poses, the
left perturbation of a pose, cross-product matrices.

Convention: poses camera-to-world (..., 4, 4), ``p_world = R p_cam + t``; rotation vectors in radians; a
perturbation ``d`` (6,) of a pose ``E`` is ``exp(d) E``: rotation vector, then translation difference, both in the
axes of the frame E maps into. The torch twins (batched, differentiable) are in :mod:`ocalib.geometry.pose` and
:mod:`ocalib.geometry.quaternion`.
"""

from __future__ import annotations

import numpy as np


def cross_matrix(v: np.ndarray) -> np.ndarray:
    """Cross-product (skew-symmetric) matrices of vectors (..., 3) -> (..., 3, 3): ``cross_matrix(a) @ b = a x b``."""
    v = np.asarray(v)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2], out[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    return out - out.swapaxes(-1, -2)


def so3_exp(w: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of rotation vectors (..., 3) (Rodrigues, exact for every angle)."""
    w = np.asarray(w, dtype=np.float64)
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    small = theta < 1e-8
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1 - theta**2 / 6, np.sin(theta) / safe)
    b = np.where(small, 0.5 - theta**2 / 24, (1 - np.cos(theta)) / safe**2)
    K = cross_matrix(w)
    return np.eye(3) + a * K + b * (K @ K)


def _sin_axis_cos(R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``sin(angle) * axis`` (..., 3) (the skew part of R) and ``cos(angle)`` (...) of rotations (..., 3, 3)."""
    w = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1) / 2
    return w, (np.trace(R, axis1=-2, axis2=-1) - 1) / 2


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3) (axis times angle in [0, pi], radians) of rotation matrices (..., 3, 3), the inverse
    of :func:`so3_exp`: the axis from the skew part below 90 degrees (accurate near 0), from the symmetric part above
    (accurate near 180 degrees)."""
    R = np.asarray(R, dtype=np.float64)
    w, cos = _sin_axis_cos(R)
    sin = np.linalg.norm(w, axis=-1)
    angle = np.arctan2(sin, cos)
    near_zero = w * (angle / np.where(sin > 0, sin, 1.0))[..., None]
    M = (R + R.swapaxes(-1, -2)) / 2 - cos[..., None, None] * np.eye(3)  # (1 - cos) axis axis^T
    pivot = np.diagonal(M, axis1=-2, axis2=-1).argmax(-1)
    column = np.take_along_axis(M, pivot[..., None, None], -1)[..., 0]
    axis = column / np.maximum(np.linalg.norm(column, axis=-1, keepdims=True), 1e-300)
    axis = np.where((axis * w).sum(-1, keepdims=True) < 0, -axis, axis)
    return np.where((cos < 0)[..., None], axis * angle[..., None], near_zero)


def rotation_angle_deg(R: np.ndarray) -> np.ndarray:
    """Rotation angles in degrees, [0, 180], of rotation matrices (..., 3, 3) (atan2 form, accurate near 0 and 180;
    ``rotation_angle_deg(A.T @ B)``: the angle between rotations A and B)."""
    w, cos = _sin_axis_cos(np.asarray(R))
    return np.degrees(np.arctan2(np.linalg.norm(w, axis=-1), cos))


def invert(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid poses (..., 4, 4) through R^T."""
    out = np.zeros_like(T)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -(Rt @ T[..., :3, 3:])[..., 0]
    out[..., 3, 3] = 1
    return out


def chain_motions(motions: np.ndarray) -> np.ndarray:
    """Frame-to-frame motions ``T_{t-1,t}`` (N, 4, 4) -> camera-to-first-frame poses (N + 1, 4, 4):
    ``P_0 = I``, ``P_t = P_{t-1} T_{t-1,t}``."""
    poses = np.empty((len(motions) + 1, 4, 4))
    poses[0] = np.eye(4)
    for t, motion in enumerate(motions, 1):
        poses[t] = poses[t - 1] @ motion
    return poses


def innovation(reference: np.ndarray, estimate: np.ndarray) -> np.ndarray:
    """(6,) ``d`` with ``estimate = exp(d) reference`` for poses (4, 4): rotation vector (rad) and translation
    difference."""
    return np.concatenate([so3_log(estimate[:3, :3] @ reference[:3, :3].T), estimate[:3, 3] - reference[:3, 3]])


def perturbed(reference: np.ndarray, d: np.ndarray) -> np.ndarray:
    """``exp(d) reference`` (4, 4) of a pose (4, 4) and a perturbation (6,), the inverse of :func:`innovation`."""
    out = reference.copy()
    out[:3, :3] = so3_exp(d[:3]) @ reference[:3, :3]
    out[:3, 3] = reference[:3, 3] + d[3:]
    return out
