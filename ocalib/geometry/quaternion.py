"""Unit quaternions, (w, x, y, z) order as in kornia.

Written for speed on tiny batches (the calibration head calls them every frame): the linear maps
(product matrices, Shepperd's candidates) are single matrix products with constant bases, so each
function is a handful of tensor operations; all are differentiable, for any leading batch shape.
"""

from __future__ import annotations

import torch
from torch import Tensor

from ocalib.geometry.constants import constant_cache


def quaternion_multiply(p: Tensor, q: Tensor) -> Tensor:
    """Hamilton product ``p * q``. Shapes (..., 4) -> (..., 4)."""
    return (left_product_matrix(p) @ q.unsqueeze(-1)).squeeze(-1)


def quaternion_conjugate(q: Tensor) -> Tensor:
    """``q*`` = (w, -x, -y, -z), the inverse of a unit quaternion. Shape (..., 4) -> (..., 4)."""
    return torch.cat([q[..., :1], -q[..., 1:]], -1)


def left_product_matrix(q: Tensor) -> Tensor:
    """``L(q)`` with ``q * p = L(q) p``. Shape (..., 4) -> (..., 4, 4)."""
    return (q @ _bases(q.dtype, q.device)[0]).unflatten(-1, (4, 4))


def right_product_matrix(q: Tensor) -> Tensor:
    """``R(q)`` with ``p * q = R(q) p``. Shape (..., 4) -> (..., 4, 4)."""
    return (q @ _bases(q.dtype, q.device)[1]).unflatten(-1, (4, 4))


def _left(w, x, y, z):
    return [[w, -x, -y, -z], [x, w, -z, y], [y, z, w, -x], [z, -y, x, w]]


def _right(w, x, y, z):
    return [[w, -x, -y, -z], [x, w, z, -y], [y, -z, w, x], [z, y, -x, w]]


def _shepperd(r00, r01, r02, r10, r11, r12, r20, r21, r22):
    """Row i: ``4 q_i q``, written with the i-th pivot ``4 q_i^2 = 1 (+-) r00 (+-) r11 (+-) r22``."""
    return [
        [1 + r00 + r11 + r22, r21 - r12, r02 - r20, r10 - r01],
        [r21 - r12, 1 + r00 - r11 - r22, r01 + r10, r02 + r20],
        [r02 - r20, r01 + r10, 1 - r00 + r11 - r22, r12 + r21],
        [r10 - r01, r02 + r20, r12 + r21, 1 - r00 - r11 + r22],
    ]


@constant_cache
def _bases(dtype: torch.dtype, device: torch.device) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Constant matrices of the linear maps above: L (4, 16), R (4, 16), Shepperd (9, 16) + offset (16,)."""

    def as_rows(f, n):  # row i: the flattened f(e_i), as tensor operations (torch.compile traces them)
        entries = f(*torch.eye(n, dtype=torch.float64).unbind(-1))  # 4 x 4 entries, each (n,): over e_1..e_n
        return (
            torch.stack(
                [torch.stack([torch.as_tensor(e, dtype=torch.float64).expand(n) for e in row]) for row in entries]
            )
            .reshape(16, n)
            .T
        )

    offset = torch.tensor(sum(_shepperd(*[0.0] * 9), []), dtype=torch.float64)
    bases = (as_rows(_left, 4), as_rows(_right, 4), as_rows(_shepperd, 9) - offset, offset)
    return tuple(b.to(dtype=dtype, device=device) for b in bases)


def canonical_quaternion(q: Tensor) -> Tensor:
    """The sign of ``q`` with ``w >= 0`` (q and -q are the same rotation). Shape (..., 4)."""
    return torch.where(q[..., :1] < 0, -q, q)


def rotation_matrix_to_quaternion(R: Tensor) -> Tensor:
    """Rotation matrix (..., 3, 3) -> unit quaternion (..., 4), (w, x, y, z), with ``w >= 0``.

    Shepperd's method: of the four algebraically equal formulas, each element uses the one with the
    largest pivot, so the result is accurate for every rotation angle (including 180 degrees).
    """
    _, _, basis, offset = _bases(R.dtype, R.device)
    candidates = (R.flatten(-2) @ basis + offset).unflatten(-1, (4, 4))
    pivot = torch.diagonal(candidates, dim1=-2, dim2=-1).argmax(-1, keepdim=True)
    q = torch.take_along_dim(candidates, pivot[..., None], dim=-2).squeeze(-2)
    return canonical_quaternion(q / q.norm(dim=-1, keepdim=True))


def quaternion_to_rotation_matrix(q: Tensor) -> Tensor:
    """Quaternion (..., 4), (w, x, y, z), any norm > 0 -> rotation matrix (..., 3, 3).

    ``q * p * conj(q) = L(q) R(q)^T p`` for unit q; the rotation is its lower-right 3x3 block.
    """
    q = q / q.norm(dim=-1, keepdim=True)
    return (left_product_matrix(q) @ right_product_matrix(q).mT)[..., 1:, 1:]


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


def so3_exp(w: Tensor) -> Tensor:
    """Rotation matrices (..., 3, 3) from rotation vectors (..., 3), through the quaternion (exact for all angles;
    numpy: :func:`ocalib.geometry.se3.so3_exp`)."""
    theta = w.norm(dim=-1, keepdim=True)
    half = theta / 2
    # sin(x)/x written so that it is smooth at 0
    scale = torch.where(theta > 1e-8, torch.sin(half) / theta.clamp_min(1e-300), 0.5 - theta**2 / 48)
    return quaternion_to_rotation_matrix(torch.cat([torch.cos(half), scale * w], -1))
