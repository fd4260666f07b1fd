"""Rotations as people read them, for numpy (w, x, y, z) quaternions: rotation vectors, roll / pitch / yaw, text.

Convention: quaternions (w, x, y, z) as in kornia; ``R = Rz(yaw) Ry(pitch) Rx(roll)``; angles in degrees unless
a name says radians.
"""

from __future__ import annotations

import numpy as np


def rotation_error_deg(q: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3) in degrees of ``R_reference^T R`` for (w, x, y, z) quaternions q (..., 4) and one
    reference (4,): about the axes of the frame R maps from (camera k's)."""
    return np.rad2deg(rotation_vector(_multiply(_conjugate(reference), q)))


def _conjugate(q: np.ndarray) -> np.ndarray:
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def _multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of (w, x, y, z) quaternions, broadcast."""
    aw, av, bw, bv = a[..., :1], a[..., 1:], b[..., :1], b[..., 1:]
    return np.concatenate([aw * bw - (av * bv).sum(-1, keepdims=True), aw * bv + bw * av + np.cross(av, bv)], -1)


def rotation_vector(q: np.ndarray) -> np.ndarray:
    """(..., 4) quaternions -> (..., 3) rotation vectors in radians (the shorter way round)."""
    q = np.where(q[..., :1] < 0, -q, q)
    norm = np.linalg.norm(q[..., 1:], axis=-1, keepdims=True)
    angle = 2 * np.arctan2(norm, q[..., :1])
    return q[..., 1:] * np.where(norm > 1e-12, angle / np.maximum(norm, 1e-300), 2.0)


def angles_text(q: np.ndarray) -> str:
    """``120.02 deg about (+0.002, +1.000, +0.000); roll, pitch, yaw +179.8, +60.0, +179.7 deg`` of a (w, x, y, z)
    quaternion: the rotation's angle and axis, then its roll, pitch and yaw (``R = Rz(yaw) Ry(pitch) Rx(roll)``)."""
    rv = np.rad2deg(rotation_vector(np.asarray(q, dtype=np.float64)))
    angle = float(np.linalg.norm(rv))
    axis = rv / angle if angle > 0 else np.array([1.0, 0.0, 0.0])
    return (
        f"{angle:.2f} deg about ({', '.join(f'{v:+.3f}' for v in axis)}); roll, pitch, yaw "
        f"{', '.join(f'{v:+.1f}' for v in np.where(rpy_deg(q) <= -179.95, 180.0, rpy_deg(q)))} deg"
    )


def rpy_deg(q: np.ndarray) -> np.ndarray:
    """Roll, pitch, yaw in degrees of ``R = Rz(yaw) Ry(pitch) Rx(roll)`` for a (w, x, y, z) quaternion."""
    w, x, y, z = q
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1, 1))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return np.rad2deg([roll, pitch, yaw])


GIMBAL_LOCK = 1e-12  # |cos(pitch)| under this: roll and yaw turn about one axis, and yaw is taken as 0


def rpy_radians(R: np.ndarray) -> np.ndarray:
    """Roll, pitch, yaw in radians (3,) of a rotation matrix (3, 3) with ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (URDF's
    fixed-axis rpy), pitch in [-pi/2, pi/2].

    Accurate for every rotation, gimbal lock included: yaw is read first (0 at the lock, where only roll -+ yaw is
    defined), then pitch and roll from ``Rz(yaw)^T R = Ry(pitch) Rx(roll)``, whose entries hold them at full precision.
    """
    R = np.asarray(R, dtype=np.float64)
    yaw = np.arctan2(R[1, 0], R[0, 0]) if np.hypot(R[0, 0], R[1, 0]) > GIMBAL_LOCK else 0.0
    c, s = np.cos(yaw), np.sin(yaw)
    M = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]]) @ R
    # cos(pitch) = M[0, 0] >= 0; at the lock its rounding may go below 0, which would put pitch an ulp past pi/2
    return np.array([np.arctan2(-M[1, 2], M[1, 1]), np.arctan2(-M[2, 0], abs(M[0, 0])), yaw])
