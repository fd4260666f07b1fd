"""Joint refinement of rotation, translation and scale on the kept statistics.

The closed forms solve rotation first (quaternion rows) and then translation and scale with that rotation.
But the translation rows ``(I - R0) dT + s dR t1 = t0`` also constrain ``dR`` (through ``dR t1``, with the
motion's length as lever arm). :func:`joint_refine` minimises both at once,

    ``C(dR, dT, s) = q^T M q / sr^2 + E_t(dT, s dR) / st^2``,

where ``M`` is the rotation system's Gram matrix (``V diag(S^2) V^T``), ``E_t`` the translation residual of
the moment ``Z`` (a quadratic in ``y = (dT, vec(s dR))``, see
:func:`~ocalib.calib.stages.handeye.translation_quadratic`), and the weights are residual variances: ``sr^2 = q^T M q /
(2 n - 3)`` and ``st^2 = E_t / (3 n - 4)`` (as in the uncertainty of :mod:`ocalib.calib.stages.rotation` and
:mod:`ocalib.calib.stages.translation`). With rows in both directions (:mod:`ocalib.calib.stages.handeye`) each
direction's rows are a group with a variance of its own, ``E_t`` becoming ``E_forward / st_f^2 + E_reverse / st_r^2``:
which direction is the cleaner depends on where a front end's noise sits (in the frame a step starts from or the one it
ends in), and the data say which. The variances are first those of the closed form, whose translation residual the
rotation-first solve inflates; after ``steps`` steps they are re-estimated at the refined estimate and
``REWEIGHT_STEPS`` more steps follow (measured in batch on a walking rig under drift, median rotation error 0.0281 ->
0.0254 deg, and 0.0262 -> 0.0218 with the noise at each step's start: ``docs/simulation.md``). Every term comes from
O(1) statistics, so the refinement is O(1) per frame and equals the batch solve of all rows with the same two rounds of
weights (:func:`~ocalib.calib.drivers.batch.batch_calibrate`).

Steps start from the closed form: one Gauss-Newton step, then Newton steps (the exact Hessian in the local
rotation coordinates ``dq = q * (1, d/2) / |.|``, which converges quadratically near the minimum). The result is
kept only where its cost, under the final weights, is below the closed form's (and finite); elsewhere, and where
``active`` is False, the closed form is returned.

:func:`refine_estimate` applies it to the closed form of :mod:`ocalib.calib.stages.solve` where two rotation directions
are excited and the motion is not planar (``mode=True``), or only where the rotation rows alone leave the rotation
unobservable (``mode="unobservable"``: for monocular front ends, see :data:`REFINE_MODES`). The compiled twins are in
:mod:`ocalib.calib.stages.refine_kernel`.

Convention: ``dR`` (from the quaternion ``q``, w, x, y, z) and ``dT`` give ``T_cam0_camk``; ``s`` multiplies
camera-k units into camera-0 units.
"""

from __future__ import annotations

import torch
from torch import Tensor

from ocalib.calib.stages.rotation import RotationSystem, excited, rotation_gram
from ocalib.geometry.constants import constant_cache
from ocalib.geometry.quaternion import canonical_quaternion, left_product_matrix, quaternion_to_rotation_matrix

# The joint refinement lets the translation rows move the rotation. Where those rows are trustworthy (poses from
# SLAM, metric VO) that makes it more accurate (docs/simulation.md: 0.137 vs 0.191 deg on OpenCV's protocol). A
# monocular front end (OpenCV VO, a pose network) gets translation directions wrong in a biased way (the
# rotation-translation ambiguity): the refinement weighs rows by their scatter, which does not see a bias, and
# pulls the rotation off (measured on the held-out handheld rig: OpenCV VO 1.6 deg closed form vs 5.7 refined; the
# networks 5.5 vs 6.9, 5.7 vs 13.5). "unobservable" refines only where the rotation needs the translation rows:
# near-planar motion whose third rotation direction the rotation rows do not fix.
REFINE_MODES = (True, False, "unobservable")
REFINE_STEPS = 3  # one Gauss-Newton step and two Newton steps at the closed form's variances
REWEIGHT_STEPS = 3  # Newton steps at the variances of the refined estimate


def refine_estimate(
    est: dict[str, Tensor],
    rotation: RotationSystem,
    quadratic: tuple[Tensor, Tensor, Tensor],
    translation_rows: Tensor,
    mode: bool | str = True,
    steps: int = REFINE_STEPS,
    reverse: tuple[Tensor, Tensor, Tensor] | None = None,
) -> dict[str, Tensor]:
    """The closed form ``est`` (:func:`~ocalib.calib.stages.solve.closed_form`) refined jointly where ``mode`` (one of
    :data:`REFINE_MODES`) asks and at least two rotation directions are excited, the motion is not planar and there
    are 3 translation rows at least; ``refined`` says where the refinement was accepted.

    Args: ``rotation`` and ``quadratic`` ``(P, p, c)`` of the statistics the closed form came from, the weighted
    number of translation rows (...), the refinement's ``steps``, and the reverse rows' share of ``quadratic``
    (``reverse``, None with rows in one direction). Kernel twin:
    :func:`ocalib.calib.stages.refine_kernel.refine_estimate`.
    """
    if not mode or steps == 0:
        return est
    active = excited(est["rotation_singular_values"], rotation.rotation_rows, 1) & ~est["planar_motion"]
    active = active & (translation_rows >= 3)
    if mode == "unobservable":
        active = active & ~est["rotation_observable"]
    M = rotation_gram(rotation.S2, rotation.V)
    x = torch.cat([est["translation"], est["scale"].unsqueeze(-1)], -1)
    quat, x, refined = joint_refine(M, quadratic, est["quaternion"], x, rotation.rotation_rows, translation_rows,
                                    active, steps, reverse)  # fmt: skip
    dR = torch.where(refined[..., None, None], quaternion_to_rotation_matrix(quat), est["rotation"])
    return {
        **est,
        "quaternion": quat,
        "rotation": dR,
        "translation": x[..., :3],
        "scale": x[..., 3],
        "refined": refined,
    }


def joint_refine(
    M: Tensor,
    quadratic: tuple[Tensor, Tensor, Tensor],
    quat: Tensor,
    x: Tensor,
    rotation_rows: Tensor,
    translation_rows: Tensor,
    active: Tensor,
    steps: int = REFINE_STEPS,
    reverse: tuple[Tensor, Tensor, Tensor] | None = None,
) -> tuple[Tensor, Tensor, Tensor]:
    """Refine ``(q, dT, s)`` jointly.

    Args:
        M: (..., 4, 4) Gram matrix of the weighted rotation rows. quadratic: ``(P, p, c)`` of the translation
            moment. quat: (..., 4) closed-form rotation. x: (..., 4) closed-form ``(dT, s)``.
        rotation_rows, translation_rows: (...) weighted numbers of motion pairs behind ``M`` and the moment.
        active: (...) bool, where to refine. steps: Gauss-Newton + Newton steps before the variances are
            re-estimated (then ``REWEIGHT_STEPS`` more; none if ``steps`` is 0).
        reverse: ``(P, p, c)`` of the reverse rows (part of ``quadratic``), weighed apart; None: one group.

    Returns:
        quat (..., 4), x (..., 4) and ``refined`` (...) bool (active and accepted).
    """
    groups = row_groups(quadratic, reverse)
    dtype, device = M.dtype, M.device
    _, newton_s, newton_1, newton_r = _bases(dtype, device)
    Er0, Et0 = group_costs(M, groups, quat, x)  # the closed form's
    wr, wt = _group_weights(M, groups, Er0, Et0, rotation_rows, translation_rows, active)
    weighted = _weighted(groups, wt)
    eye7 = torch.eye(7, dtype=dtype, device=device)

    q, s_, dT = quat, x[..., 3:], x[..., :3]
    for step in range(steps + REWEIGHT_STEPS if steps else 0):
        if step == steps:  # the residual variances at the refined estimate
            costs = group_costs(M, groups, canonical_quaternion(q), torch.cat([dT, s_], -1))
            wr, wt = _group_weights(M, groups, *costs, rotation_rows, translation_rows, active)
            weighted = _weighted(groups, wt)
        H, g, dR, Jq, r, Mq = _system(M, *weighted, q, s_, dT, wr)
        if step > 0:  # Newton: the second derivatives of m and q, contracted with the gradient
            D = (dR.mT @ r[..., 3:].unflatten(-1, (3, 3))).flatten(-2)  # dR^T R, R = gradient in s dR
            H = H + (s_ * D @ newton_s + D @ newton_1 - 0.25 * (Mq * q).sum(-1, keepdim=True) * newton_r).unflatten(
                -1, (7, 7)
            )
        H = torch.where(
            active[..., None, None],
            H + 1e-14 * H.diagonal(dim1=-2, dim2=-1).abs().mean(-1)[..., None, None] * eye7,
            eye7,
        )
        d, _ = torch.linalg.solve_ex(H, -torch.where(active[..., None], g, 0.0))
        q = q + (Jq @ d[..., :3].unsqueeze(-1)).squeeze(-1)
        q = q / q.norm(dim=-1, keepdim=True)
        s_, dT = s_ + d[..., 3:4], dT + d[..., 4:]

    q, xr = canonical_quaternion(q), torch.cat([dT, s_], -1)
    Er, Et = group_costs(M, groups, q, xr)
    ok = active & (wr * Er + (wt * Et).sum(-1) <= wr * Er0 + (wt * Et0).sum(-1))
    ok = ok & q.isfinite().all(-1) & xr.isfinite().all(-1)
    return torch.where(ok[..., None], q, quat), torch.where(ok[..., None], xr, x), ok


def row_groups(quadratic: tuple[Tensor, Tensor, Tensor], reverse: tuple[Tensor, Tensor, Tensor] | None):
    """The translation rows' groups as one quadratic with a group dimension G: ``P`` (..., G, 12, 12), ``p``
    (..., G, 12), ``c`` (..., G); the forward and the reverse rows (G = 2) or all rows (G = 1, ``reverse`` None)."""
    if reverse is None:
        return tuple(t.unsqueeze(d) for t, d in zip(quadratic, (-3, -2, -1)))
    return tuple(torch.stack([a - b, b], d) for a, b, d in zip(quadratic, reverse, (-3, -2, -1)))


def group_costs(M: Tensor, groups: tuple[Tensor, Tensor, Tensor], q: Tensor, x: Tensor) -> tuple[Tensor, Tensor]:
    """:func:`costs` with the translation residual of each group of :func:`row_groups`: ``Er`` (...), ``Et``
    (..., G)."""
    P, p, c = groups
    Er, Et = costs(M.unsqueeze(-3), P, p, c, q.unsqueeze(-2), x.unsqueeze(-2))
    return Er[..., 0], Et


def _group_weights(M, groups, Er, Et, rotation_rows, translation_rows, active) -> tuple[Tensor, Tensor]:
    """The weights ``1 / sr^2`` (...) and ``1 / st_g^2`` (..., G) of the residuals ``Er``, ``Et`` of
    :func:`group_costs` (0 for an empty group); 1 where not ``active`` (harmless numbers: nothing non-finite reaches
    the gradient through the discarded branch)."""
    wr, wt = _weights(M, groups[2], Er, Et, rotation_rows, translation_rows.unsqueeze(-1))
    # A group without rows (the reverse rows of one-way pairs) weighs 0. A pair's rows in the two directions share its
    # noise: the groups' weights are halved (the weight of all rows as one group when both are alike).
    wt = torch.where(groups[2] > 0, wt, 0.0)
    wt = wt / (groups[2] > 0).sum(-1, keepdim=True).clamp_min(1)
    return torch.where(active, wr, 1.0), torch.where(active.unsqueeze(-1), wt, 1.0)


def joint_covariance(
    M: Tensor,
    quadratic: tuple[Tensor, Tensor, Tensor],
    quat: Tensor,
    x: Tensor,
    rotation_rows: Tensor,
    translation_rows: Tensor,
    reverse: tuple[Tensor, Tensor, Tensor] | None = None,
) -> Tensor:
    """Covariance (..., 7, 7) of the refined estimate, unknowns ordered (d, s, dT) with ``d`` the rotation
    vector error about camera k's axes: the inverse Gauss-Newton Hessian of the cost weighted by the residual
    variances at the estimate (each group of rows, as :func:`joint_refine` weighs them; each weighted residual then
    has unit variance). Inf without degrees of freedom."""
    groups = row_groups(quadratic, reverse)
    active = torch.ones_like(rotation_rows, dtype=torch.bool)
    wr, wt = _group_weights(M, groups, *group_costs(M, groups, quat, x), rotation_rows, translation_rows, active)
    H = _system(M, *_weighted(groups, wt), quat, x[..., 3:], x[..., :3], wr)[0]
    cov, info = torch.linalg.inv_ex(H)
    free = (2 * rotation_rows - 3 <= 0) | (3 * translation_rows - 4 <= 0) | (info != 0)
    return torch.where(free[..., None, None], torch.inf, cov)


def _weights(M, c, Er, Et, rotation_rows, translation_rows) -> tuple[Tensor, Tensor]:
    """``1 / sr^2, 1 / st^2`` (...) from the residuals (floors keep noise-free data finite)."""
    tiny = torch.finfo(M.dtype).eps ** 2
    wr = (2 * rotation_rows - 3).clamp_min(1) / (Er + tiny * M.diagonal(dim1=-2, dim2=-1).sum(-1)).clamp_min(1e-300)
    wt = (3 * translation_rows - 4).clamp_min(1) / (Et + tiny * c).clamp_min(1e-300)
    return wr, wt


def _weighted(groups: tuple[Tensor, Tensor, Tensor], wt: Tensor) -> tuple[Tensor, Tensor]:
    """``(P, p)`` of the translation rows, each group of :func:`row_groups` times its weight ``wt`` (..., G)."""
    return (wt[..., None, None] * groups[0]).sum(-3), (wt[..., None] * groups[1]).sum(-2)


def _system(M, P, p, q, s, dT, wr) -> tuple[Tensor, ...]:
    """Gauss-Newton system at ``(q, s, dT)`` of ``wr q^T M q + E_t`` (``P``, ``p`` weighted): H (..., 7, 7), g (..., 7)
    (half the gradient), and the pieces
    the Newton terms and the update reuse: dR, Jq = dq/dd (..., 4, 3), r (half the gradient of the weighted
    E_t in y, (..., 12)), wr M q (..., 4).

    Unknowns (d, s, dT), d the local rotation (q <- q * (1, d/2) / |.|). With y = (dT, m), m = vec(s dR):
    dm/dd_k = s vec(dR [e_k]x), dm/ds = vec(dR), dy/ddT = (I, 0). So J_y = [[0, I], [C, 0]] with
    C = [s dR G | vec(dR)] (9, 4), and J_y^T P J_y, J_y^T (P y - p) follow from blocks of P.
    """
    G = _bases(M.dtype, M.device)[0]
    wr = wr[..., None, None]
    dR = quaternion_to_rotation_matrix(q)
    m = dR.flatten(-2)
    C = torch.cat([s.unsqueeze(-1) * (dR.unsqueeze(-3) @ G).flatten(-2).mT, m.unsqueeze(-1)], -1)
    y = torch.cat([dT, s * m], -1)
    r = (P @ y.unsqueeze(-1)).squeeze(-1) - p
    K = torch.cat([P[..., :, 3:] @ C, P[..., :, :3]], -1)  # P J_y (12, 7)
    H = torch.cat([C.mT @ K[..., 3:, :], K[..., :3, :]], -2)
    g = torch.cat([(C.mT @ r[..., 3:].unsqueeze(-1)).squeeze(-1), r[..., :3]], -1)
    Jq = 0.5 * left_product_matrix(q)[..., :, 1:]
    Mq = wr.squeeze(-1) * (M @ q.unsqueeze(-1)).squeeze(-1)
    H = H + torch.nn.functional.pad(wr * Jq.mT @ M @ Jq, (0, 4, 0, 4))
    g = g + torch.nn.functional.pad((Jq.mT @ Mq.unsqueeze(-1)).squeeze(-1), (0, 4))
    return H, g, dR, Jq, r, Mq


def costs(M: Tensor, P: Tensor, p: Tensor, c: Tensor, q: Tensor, x: Tensor) -> tuple[Tensor, Tensor]:
    """Rotation residual ``q^T M q`` and translation residual ``E_t`` (...) at ``(q, x)``: the weighted sums of
    squares of the rotation rows (Gram matrix ``M``) and of the translation rows (quadratic ``(P, p, c)``)."""
    dR = quaternion_to_rotation_matrix(q)
    y = torch.cat([x[..., :3], x[..., 3:] * dR.flatten(-2)], -1)
    Er = (q.unsqueeze(-2) @ M @ q.unsqueeze(-1)).squeeze((-1, -2))
    Et = (y.unsqueeze(-2) @ P @ y.unsqueeze(-1)).squeeze((-1, -2)) - 2 * (p * y).sum(-1) + c
    return Er, Et


@constant_cache
def _bases(dtype: torch.dtype, device: torch.device) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Constants, for the unknowns ordered (d, s, dT): ``G`` (3, 3, 3) the generators ``[e_k]x``; the Newton
    terms as maps from ``vec(D)`` (9) to the flattened 7x7 Hessian: ``newton_s`` (9, 49), times s, for
    ``<D, (G_k G_l + G_l G_k) / 2>`` in the (d, d) block (the second derivative of ``dR R(d)``), ``newton_1``
    (9, 49) for ``<D, G_k>`` in the (d, s) entries, and ``newton_r`` (49,) the identity of the (d, d) block
    (the second derivative of ``q * (1, d/2) / |.|`` is ``-q / 4``)."""
    eye = torch.eye(3, dtype=torch.float64)
    G = torch.stack([torch.linalg.cross(eye[k].expand(3, 3), eye, dim=-1).mT for k in range(3)])
    newton_s = torch.zeros(9, 7, 7, dtype=torch.float64)
    newton_1 = torch.zeros(9, 7, 7, dtype=torch.float64)
    newton_r = torch.zeros(7, 7, dtype=torch.float64)
    for k in range(3):
        for l in range(3):
            newton_s[:, k, l] = (0.5 * (G[k] @ G[l] + G[l] @ G[k])).flatten()
        newton_1[:, k, 3] = newton_1[:, 3, k] = G[k].flatten()
        newton_r[k, k] = 1.0
    out = G, newton_s.flatten(1), newton_1.flatten(1), newton_r.flatten()
    return tuple(t.to(dtype=dtype, device=device) for t in out)
