"""Rigid poses as 4x4 homogeneous matrices (..., 4, 4).

Convention: a pose is camera-to-world, ``p_world = R p_cam + t``. ``relative_pose(T_a, T_b)`` is the
pose of b in a's frame, ``T_a^-1 T_b``.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor


def make_pose(R: Tensor, t: Tensor) -> Tensor:
    """Rotation (..., 3, 3) and translation (..., 3) -> pose (..., 4, 4)."""
    top = torch.cat([R, t.unsqueeze(-1)], -1)
    bottom = torch.zeros_like(top[..., :1, :])
    bottom[..., 0, 3] = 1
    return torch.cat([top, bottom], -2)


def invert_pose(T: Tensor) -> Tensor:
    """Inverse of rigid poses (..., 4, 4), using R^T (no general matrix inverse)."""
    Rt = T[..., :3, :3].mT
    return make_pose(Rt, -(Rt @ T[..., :3, 3:]).squeeze(-1))


def relative_pose(T_a: Tensor, T_b: Tensor) -> Tensor:
    """Pose of b in a's frame, ``T_a^-1 T_b``. Shapes (..., 4, 4)."""
    return invert_pose(T_a) @ T_b


def rereference(T: Tensor) -> Tensor:
    """Re-reference a trajectory (N, 4, 4) or (..., N, 4, 4) to its first frame: ``T_0^-1 T_t``."""
    return relative_pose(T[..., :1, :, :], T)


def orthonormality_error(R: Tensor) -> Tensor:
    """Largest deviation of ``R^T R`` from the identity and of det(R) from 1. Shape (..., 3, 3) -> (...)."""
    eye = torch.eye(3, dtype=R.dtype, device=R.device)
    gram = (R.mT @ R - eye).abs().flatten(-2).amax(-1)
    det = (torch.linalg.cross(R[..., 0, :], R[..., 1, :], dim=-1) * R[..., 2, :]).sum(-1)  # no LU for a 3x3
    return torch.maximum(gram, (det - 1).abs())


def cross_matrix(v: np.ndarray) -> np.ndarray:
    """Cross-product (skew-symmetric) matrices of vectors (..., 3) -> (..., 3, 3), numpy: ``cross_matrix(a) @ b =
    a x b``."""
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2], out[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    return out - out.swapaxes(-1, -2)


def chain_motions(motions: np.ndarray) -> np.ndarray:
    """Frame-to-frame motions ``T_{t-1,t}`` (N, 4, 4) -> camera-to-first-frame poses (N + 1, 4, 4):
    ``P_0 = I``, ``P_t = P_{t-1} T_{t-1,t}``."""
    poses = np.empty((len(motions) + 1, 4, 4))
    poses[0] = np.eye(4)
    for t, motion in enumerate(motions, 1):
        poses[t] = poses[t - 1] @ motion
    return poses


UNOBSERVABLE_AXIS_SHARE = 0.1  # an axis with this share of an unobservable direction has no std (a car's y, not x)


def touched_axes(directions: np.ndarray, share: float = UNOBSERVABLE_AXIS_SHARE) -> np.ndarray:
    """(3,) bool: the axes that any of the unit ``directions`` (n, 3) has a share over ``share`` of (none for n = 0);
    with unobservable translation directions, the axes whose 1-sigma is not a measurement."""
    return (np.abs(np.asarray(directions, dtype=float).reshape(-1, 3)) > share).any(0)
