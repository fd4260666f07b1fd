"""Rigid poses as 4x4 homogeneous matrices (..., 4, 4), in torch (batched, differentiable; numpy:
:mod:`ocalib.geometry.se3`).

Convention: a pose is camera-to-world, ``p_world = R p_cam + t``. ``relative_pose(T_a, T_b)`` is the
pose of b in a's frame, ``T_a^-1 T_b``.
"""

from __future__ import annotations

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
