"""Unit quaternions, (w, x, y, z) order as in kornia.

Written for speed on tiny batches (the calibration head calls them every frame): each function
is a handful of tensor operations, differentiable, and works for any leading batch shape.
"""

from __future__ import annotations

import torch
from torch import Tensor


def quaternion_multiply(p: Tensor, q: Tensor) -> Tensor:
    """Hamilton product ``p * q``. Shapes (..., 4) -> (..., 4)."""
    return (left_product_matrix(p) @ q.unsqueeze(-1)).squeeze(-1)


def left_product_matrix(q: Tensor) -> Tensor:
    """``L(q)`` with ``q * p = L(q) p``. Shape (..., 4) -> (..., 4, 4)."""
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        [
            torch.stack([w, -x, -y, -z], -1),
            torch.stack([x, w, -z, y], -1),
            torch.stack([y, z, w, -x], -1),
            torch.stack([z, -y, x, w], -1),
        ],
        -2,
    )


def right_product_matrix(q: Tensor) -> Tensor:
    """``R(q)`` with ``p * q = R(q) p``. Shape (..., 4) -> (..., 4, 4)."""
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        [
            torch.stack([w, -x, -y, -z], -1),
            torch.stack([x, w, z, -y], -1),
            torch.stack([y, -z, w, x], -1),
            torch.stack([z, y, -x, w], -1),
        ],
        -2,
    )


def canonical_quaternion(q: Tensor) -> Tensor:
    """The sign of ``q`` with ``w >= 0`` (q and -q are the same rotation). Shape (..., 4)."""
    sign = torch.where(q[..., :1] < 0, -1.0, 1.0).to(q.dtype)
    return q * sign


def rotation_matrix_to_quaternion(R: Tensor) -> Tensor:
    """Rotation matrix (..., 3, 3) -> unit quaternion (..., 4), (w, x, y, z), with ``w >= 0``.

    Shepperd's method: of the four algebraically equal formulas, each element uses the one with the
    largest pivot, so the result is accurate for every rotation angle (including 180 degrees).
    """
    r = R.reshape(*R.shape[:-2], 9)
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = r.unbind(-1)
    # Row i is 4 * q_i * q, written with the i-th pivot 4 * q_i^2 = 1 + (+-)r00 (+-)r11 (+-)r22.
    candidates = torch.stack(
        [
            torch.stack([1 + r00 + r11 + r22, r21 - r12, r02 - r20, r10 - r01], -1),
            torch.stack([r21 - r12, 1 + r00 - r11 - r22, r01 + r10, r02 + r20], -1),
            torch.stack([r02 - r20, r01 + r10, 1 - r00 + r11 - r22, r12 + r21], -1),
            torch.stack([r10 - r01, r02 + r20, r12 + r21, 1 - r00 - r11 + r22], -1),
        ],
        -2,
    )
    pivot = torch.diagonal(candidates, dim1=-2, dim2=-1).argmax(-1, keepdim=True)
    q = torch.take_along_dim(candidates, pivot[..., None], dim=-2).squeeze(-2)
    return canonical_quaternion(q / q.norm(dim=-1, keepdim=True))


def quaternion_to_rotation_matrix(q: Tensor) -> Tensor:
    """Quaternion (..., 4), (w, x, y, z), any norm > 0 -> rotation matrix (..., 3, 3)."""
    q = q / q.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        -1,
    ).reshape(*q.shape[:-1], 3, 3)


def quaternion_angle(q: Tensor) -> Tensor:
    """Rotation angle in radians, in [0, pi], of quaternions (..., 4) (either sign)."""
    q = q / q.norm(dim=-1, keepdim=True)
    return 2 * torch.atan2(q[..., 1:].norm(dim=-1), q[..., 0].abs())


def rotation_angle(R: Tensor) -> Tensor:
    """Rotation angle in radians, in [0, pi], of rotation matrices (..., 3, 3).

    Uses atan2(|axis * sin|, cos) rather than acos(trace), which is inaccurate near 0 and pi.
    """
    skew = torch.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    cos = (R[..., 0, 0] + R[..., 1, 1] + R[..., 2, 2] - 1) / 2
    return torch.atan2(skew.norm(dim=-1) / 2, cos)
