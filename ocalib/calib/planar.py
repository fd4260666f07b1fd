"""Rotation of the rig under planar motion, recovered through the translation constraint.

When every motion rotates about the same axis (a car on a road), the rotation system has a 2-D null
space spanned by ``v3, v4`` (the last two right singular vectors): every ``dR = R_n(theta) R(v4)`` fits,
where ``n`` (camera 0's frame) is the common rotation axis. The translation equations fix ``theta``
(CamOdoCal's approach): with ``R_n(theta) = n n^T + cos(theta) (I - n n^T) + sin(theta) [n]x``,

    ``(I - R0) dT + c0 (n n^T R4) t1 + c1 ((I - n n^T) R4) t1 + c2 ([n]x R4) t1 = t0``

is linear in ``(dT, c0, c1, c2) = (dT, s, s cos(theta), s sin(theta))``. The component of ``dT``
along ``n`` (camera height for a car) is unobservable; the minimum-norm solution sets it to zero.

Convention: ``n`` and ``dT`` in camera 0's frame; quaternions (w, x, y, z).
"""

from __future__ import annotations

import torch
from torch import Tensor

from ocalib.calib.handeye import normal_equations
from ocalib.calib.translation import pinv_solve
from ocalib.geometry.quaternion import quaternion_multiply, quaternion_to_rotation_matrix


def skew(v: Tensor) -> Tensor:
    """Cross-product matrix ``[v]x`` (..., 3, 3) of vectors (..., 3)."""
    x, y, z = v.unbind(-1)
    o = torch.zeros_like(x)
    return torch.stack([o, -z, y, z, o, -x, -y, x, o], -1).reshape(*v.shape[:-1], 3, 3)


def planar_axis(V: Tensor) -> Tensor:
    """The common rotation axis ``n`` (..., 3) in camera 0's frame from the null space ``V[:, 2:]``.

    ``v4 * conj(v3)`` is a pure quaternion (``v3 . v4 = 0``): a 180-degree turn about ``n``.
    """
    v3, v4 = V[..., :, 2], V[..., :, 3]
    conj3 = v3 * v3.new_tensor([1.0, -1.0, -1.0, -1.0])
    n = quaternion_multiply(v4, conj3)[..., 1:]
    return n / n.norm(dim=-1, keepdim=True).clamp_min(1e-300)


def planar_rotation(quadratic: tuple[Tensor, Tensor, Tensor], V: Tensor) -> tuple[Tensor, Tensor]:
    """Rotation ``dR`` (..., 3, 3) for planar motion, and the axis ``n`` (..., 3).

    Args:
        quadratic: the translation moment's ``(P, p, c)`` (:func:`~ocalib.calib.handeye.translation_quadratic`).
        V: (..., 4, 4) right singular vectors of the rotation system.
    """
    n = planar_axis(V)
    R4 = quaternion_to_rotation_matrix(V[..., :, 3])
    nnT = n.unsqueeze(-1) * n.unsqueeze(-2)
    eye = torch.eye(3, dtype=V.dtype, device=V.device)
    maps = torch.stack([nnT @ R4, (eye - nnT) @ R4, skew(n) @ R4], -3)  # (..., 3, 3, 3)
    H, g, _ = normal_equations(quadratic, maps)
    c, _ = pinv_solve(H, g)
    theta = torch.atan2(c[..., 5], c[..., 4])
    dR = maps[..., 0, :, :] + torch.cos(theta)[..., None, None] * maps[..., 1, :, :]
    dR = dR + torch.sin(theta)[..., None, None] * maps[..., 2, :, :]
    return dR, n
