"""Rotation of the rig under planar motion, recovered through the translation constraint.

When every motion rotates about the same axis (a car on a road), the rotation system has a 2-D null
space spanned by ``v3, v4`` (the last two right singular vectors): every ``dR = R_n(theta) R(v4)`` fits,
where ``n`` (camera 0's frame) is the common rotation axis. The translation equations fix ``theta``
(CamOdoCal's approach): with ``R_n(theta) = n n^T + cos(theta) (I - n n^T) + sin(theta) [n]x``,

    ``(I - R0) dT + c0 (n n^T R4) t1 + c1 ((I - n n^T) R4) t1 + c2 ([n]x R4) t1 = t0``

is linear in ``(dT, c0, c1, c2) = (dT, s, s cos(theta), s sin(theta))``. The component of ``dT``
along ``n`` (camera height for a car) is unobservable; the minimum-norm solution sets it to zero.

The compiled twin is in :mod:`ocalib.calib.stages.planar_kernel`.

Convention: ``n`` and ``dT`` in camera 0's frame; quaternions (w, x, y, z).
"""

from __future__ import annotations

import torch
from torch import Tensor

from ocalib.calib.stages.handeye import normal_equations
from ocalib.calib.stages.rotation import rotation_gram
from ocalib.calib.stages.translation import pinv_solve
from ocalib.geometry.quaternion import (
    left_product_matrix,
    quaternion_conjugate,
    quaternion_multiply,
    quaternion_to_rotation_matrix,
)


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
    conj3 = quaternion_conjugate(v3)
    n = quaternion_multiply(v4, conj3)[..., 1:]
    return n / n.norm(dim=-1, keepdim=True).clamp_min(1e-300)


def planar_rotation(quadratic: tuple[Tensor, Tensor, Tensor], V: Tensor) -> tuple[Tensor, Tensor]:
    """Rotation ``dR`` (..., 3, 3) for planar motion, and the axis ``n`` (..., 3).

    Args:
        quadratic: the translation moment's ``(P, p, c)`` (:func:`~ocalib.calib.stages.handeye.translation_quadratic`).
        V: (..., 4, 4) right singular vectors of the rotation system.
    """
    n, maps = _planar_maps(V)
    H, g, _ = normal_equations(quadratic, maps)
    c, _ = pinv_solve(H, g)
    theta = torch.atan2(c[..., 5], c[..., 4])
    dR = maps[..., 0, :, :] + torch.cos(theta)[..., None, None] * maps[..., 1, :, :]
    dR = dR + torch.sin(theta)[..., None, None] * maps[..., 2, :, :]
    return dR, n


def planar_rotation_std(
    quadratic: tuple[Tensor, Tensor, Tensor],
    S: Tensor,
    V: Tensor,
    quat: Tensor,
    rotation_rows: Tensor,
    translation_rows: Tensor,
) -> Tensor:
    """1-sigma rotation error (..., 3) in radians about camera k's axes, for the planar route.

    The rotation rows fix the two directions of ``v1, v2`` (singular values ``S[0], S[1]``; noise from their
    residual at ``dq`` with ``2 n - 2`` degrees of freedom); the angle ``theta`` about the axis comes from the
    translation solve: ``theta = atan2(c2, c1)`` with the covariance ``st^2 H^+`` of ``c`` (``3 n - 6`` degrees
    of freedom), and moves the rotation about ``dR^T n`` in camera k's frame. Infinite without the degrees of
    freedom.
    """
    n, maps = _planar_maps(V)
    H, g, tt = normal_equations(quadratic, maps)
    c, H_pinv = pinv_solve(H, g)
    rss = (tt - 2 * (c * g).sum(-1) + (c.unsqueeze(-2) @ H @ c.unsqueeze(-1)).squeeze((-1, -2))).clamp_min(0)
    dof_t = 3 * translation_rows - 6
    st2 = torch.where(dof_t > 0, rss / dof_t.clamp_min(1), torch.inf)
    c1, c2 = c[..., 4], c[..., 5]
    var_theta = st2 * (c2**2 * H_pinv[..., 4, 4] + c1**2 * H_pinv[..., 5, 5] - 2 * c1 * c2 * H_pinv[..., 4, 5])
    var_theta = var_theta / (c1**2 + c2**2).square().clamp_min(1e-300)
    # The rotation rows: residual at dq, two constrained directions.
    M = rotation_gram(S.square(), V)
    dof_r = 2 * rotation_rows - 2
    Er = (quat.unsqueeze(-2) @ M @ quat.unsqueeze(-1)).squeeze((-1, -2))
    sr2 = torch.where(dof_r > 0, Er / dof_r.clamp_min(1), torch.inf)
    conj = quaternion_conjugate(quat)
    JV = 2 * left_product_matrix(conj)[..., 1:, :] @ (V[..., :, :2] / S[..., None, :2].clamp_min(1e-300))
    axis_k = (quaternion_to_rotation_matrix(quat).mT @ n.unsqueeze(-1)).squeeze(-1)
    return (sr2[..., None] * (JV * JV).sum(-1) + var_theta[..., None] * axis_k**2).sqrt()


def _planar_maps(V: Tensor) -> tuple[Tensor, Tensor]:
    """The axis ``n`` (..., 3) and the maps ``(n n^T R4, (I - n n^T) R4, [n]x R4)`` (..., 3, 3, 3)."""
    n = planar_axis(V)
    R4 = quaternion_to_rotation_matrix(V[..., :, 3])
    nnT = n.unsqueeze(-1) * n.unsqueeze(-2)
    eye = torch.eye(3, dtype=V.dtype, device=V.device)
    return n, torch.stack([nnT @ R4, (eye - nnT) @ R4, skew(n) @ R4], -3)
