"""Joint refinement of rotation, translation and scale on the kept statistics.

The closed forms solve rotation first (quaternion rows) and then translation and scale with that rotation.
But the translation rows ``(I - R0) dT + s dR t1 = t0`` also constrain ``dR`` (through ``dR t1``, with the
motion's length as lever arm). :func:`joint_refine` minimises both at once,

    ``C(dR, dT, s) = q^T M q / sr^2 + E_t(dT, s dR) / st^2``,

where ``M`` is the rotation system's Gram matrix (``V diag(S^2) V^T``), ``E_t`` the translation residual of
the moment ``Z`` (a quadratic in ``y = (dT, vec(s dR))``, see :func:`~ocalib.calib.handeye.translation_quadratic`),
and the weights are the residual variances of the closed-form estimate: ``sr^2 = q^T M q / (2 n - 3)`` and
``st^2 = E_t / (3 n - 4)`` (as in the uncertainty of :mod:`ocalib.calib.rotation` and
:mod:`ocalib.calib.translation`). Both terms come from O(1) statistics, so the refinement is O(1) per frame and
equals a batch nonlinear least-squares solve of all rows at once.

Steps start from the closed form: one Gauss-Newton step, then Newton steps (the exact Hessian in the local
rotation coordinates ``dq = q * (1, d/2) / |.|``, which converges quadratically near the minimum). The result is
kept only where its cost is below the closed form's (and finite); elsewhere, and where ``active`` is False,
the closed form is returned.

Convention: ``dR`` (from the quaternion ``q``, w, x, y, z) and ``dT`` give ``T_cam0_camk``; ``s`` multiplies
camera-k units into camera-0 units.
"""

from __future__ import annotations

from functools import lru_cache

import torch
from torch import Tensor

from ocalib.geometry.quaternion import canonical_quaternion, left_product_matrix, quaternion_to_rotation_matrix


def joint_refine(
    M: Tensor,
    quadratic: tuple[Tensor, Tensor, Tensor],
    quat: Tensor,
    x: Tensor,
    rotation_rows: Tensor,
    translation_rows: Tensor,
    active: Tensor,
    steps: int = 3,
) -> tuple[Tensor, Tensor, Tensor]:
    """Refine ``(q, dT, s)`` jointly.

    Args:
        M: (..., 4, 4) Gram matrix of the weighted rotation rows. quadratic: ``(P, p, c)`` of the translation
            moment. quat: (..., 4) closed-form rotation. x: (..., 4) closed-form ``(dT, s)``.
        rotation_rows, translation_rows: (...) weighted numbers of motion pairs behind ``M`` and the moment.
        active: (...) bool, where to refine. steps: Gauss-Newton + Newton steps.

    Returns:
        quat (..., 4), x (..., 4) and ``refined`` (...) bool (active and accepted).
    """
    P, p, c = quadratic
    dtype, device = M.dtype, M.device
    G, S2nd, E, J_dT = _bases(dtype, device)
    # Residual variances of the closed form (floors keep noise-free data finite).
    Er0, Et0 = _costs(M, P, p, c, quat, x)
    tiny = torch.finfo(dtype).eps ** 2
    wr = (2 * rotation_rows - 3).clamp_min(1) / (Er0 + tiny * M.diagonal(dim1=-2, dim2=-1).sum(-1)).clamp_min(1e-300)
    wt = (3 * translation_rows - 4).clamp_min(1) / (Et0 + tiny * c).clamp_min(1e-300)
    # Inactive entries run on harmless numbers (unit weights, an identity Hessian below), so that nothing
    # non-finite reaches the gradient through the discarded branch.
    wr, wt = torch.where(active, wr, 1.0), torch.where(active, wt, 1.0)
    # Both residuals as one weighted quadratic in u = (y, q): u^T W u - 2 b.u + const.
    W = torch.cat([
        torch.cat([wt[..., None, None] * P, P.new_zeros(*P.shape[:-2], 12, 4)], -1),
        torch.cat([M.new_zeros(*M.shape[:-2], 4, 12), wr[..., None, None] * M], -1),
    ], -2)  # fmt: skip
    b = torch.cat([wt[..., None] * p, p.new_zeros(*p.shape[:-1], 4)], -1)

    q, xr = quat, x
    for step in range(steps):
        dR = quaternion_to_rotation_matrix(q)
        s = xr[..., 3:]
        y = torch.cat([xr[..., :3], s * dR.flatten(-2)], -1)
        # Jacobian (..., 16, 7) of u = (dT, vec(s dR), q) in (d, dT, s), d the local rotation:
        # d vec(s dR) / d d_k = s vec(dR [e_k]x), dq / dd = L(q)[:, 1:] / 2.
        batch = y.shape[:-1]
        Jq = 0.5 * left_product_matrix(q)[..., :, 1:]  # (..., 4, 3)
        dRG = (dR.unsqueeze(-3) @ G).flatten(-2).mT  # (..., 9, 3)
        J_rot = torch.cat([y.new_zeros(*batch, 3, 3), s.unsqueeze(-1) * dRG, Jq], -2)
        J_scale = torch.cat([y.new_zeros(*batch, 3), dR.flatten(-2), y.new_zeros(*batch, 4)], -1).unsqueeze(-1)
        J = torch.cat([J_rot, J_dT.expand(*batch, 16, 3), J_scale], -1)
        u = torch.cat([y, q], -1)
        r = (W @ u.unsqueeze(-1)).squeeze(-1) - b  # half the cost's gradient in u
        H = J.mT @ W @ J
        g = (J.mT @ r.unsqueeze(-1)).squeeze(-1)
        if step > 0:  # Newton: second derivatives of u, contracted with r
            D = (dR.mT @ r[..., 3:12].unflatten(-1, (3, 3))).flatten(-2)  # dR^T R, R the vec(s dR) part of r
            Er_w = (r[..., 12:] * q).sum(-1, keepdim=True)  # wr q^T M q
            H = H + (s * D @ S2nd + D @ E[0] - 0.25 * Er_w * E[1]).unflatten(-1, (7, 7))
        eye = torch.eye(7, dtype=dtype, device=device)
        H = torch.where(active[..., None, None], H + 1e-14 * H.diagonal(dim1=-2, dim2=-1).abs().mean(-1)[..., None, None] * eye, eye)
        d, _ = torch.linalg.solve_ex(H, -torch.where(active[..., None], g, 0.0))
        q = q + (Jq @ d[..., :3].unsqueeze(-1)).squeeze(-1)
        q = q / q.norm(dim=-1, keepdim=True)
        xr = xr + d[..., 3:]

    q = canonical_quaternion(q)
    Er, Et = _costs(M, P, p, c, q, xr)
    ok = active & (wr * Er + wt * Et <= wr * Er0 + wt * Et0) & q.isfinite().all(-1) & xr.isfinite().all(-1)
    return torch.where(ok[..., None], q, quat), torch.where(ok[..., None], xr, x), ok


def _costs(M: Tensor, P: Tensor, p: Tensor, c: Tensor, q: Tensor, x: Tensor) -> tuple[Tensor, Tensor]:
    """Rotation residual ``q^T M q`` and translation residual ``E_t`` (...) at ``(q, x)``."""
    dR = quaternion_to_rotation_matrix(q)
    y = torch.cat([x[..., :3], x[..., 3:] * dR.flatten(-2)], -1)
    Er = (q.unsqueeze(-2) @ M @ q.unsqueeze(-1)).squeeze((-1, -2))
    Et = (y.unsqueeze(-2) @ P @ y.unsqueeze(-1)).squeeze((-1, -2)) - 2 * (p * y).sum(-1) + c
    return Er, Et


@lru_cache(maxsize=None)
def _bases(dtype: torch.dtype, device: torch.device) -> tuple:
    """Constants: ``G`` (3, 3, 3) the generators ``[e_k]x``; the Newton terms as maps from ``vec(D)`` (9) to
    the flattened 7x7 Hessian: ``S2nd`` (9, 49) for ``<D, (G_k G_l + G_l G_k) / 2>`` in the rotation block
    (times s), and ``E = (E0, E1)``: E0 (9, 49) for ``<D, G_k>`` in the rotation-scale entries, E1 (49,) the
    identity of the rotation block (the second derivative of ``q * (1, d/2) / |.|``: ``-q / 4``); ``J_dT``
    (16, 3) the Jacobian of u in dT. Made outside inference mode (autograd may use them later)."""
    with torch.inference_mode(False):
        eye = torch.eye(3, dtype=torch.float64)
        G = torch.stack([torch.linalg.cross(eye[k].expand(3, 3), eye, dim=-1).mT for k in range(3)])
        S2nd = torch.zeros(9, 7, 7, dtype=torch.float64)
        E0 = torch.zeros(9, 7, 7, dtype=torch.float64)
        E1 = torch.zeros(7, 7, dtype=torch.float64)
        for k in range(3):
            for l in range(3):
                S2nd[:, k, l] = (0.5 * (G[k] @ G[l] + G[l] @ G[k])).flatten()
            E0[:, k, 6] = E0[:, 6, k] = G[k].flatten()
            E1[k, k] = 1.0
        J_dT = torch.zeros(16, 3, dtype=torch.float64)
        J_dT[:3] = eye
        f = dict(dtype=dtype, device=device)
        return G.to(**f), S2nd.flatten(1).to(**f), (E0.flatten(1).to(**f), E1.flatten().to(**f)), J_dT.to(**f)
