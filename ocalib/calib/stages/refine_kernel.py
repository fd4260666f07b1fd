"""Compiled twins (numba) of :mod:`ocalib.calib.stages.refine`: the joint refinement of rotation, translation and scale,
for one entry (no batch dimension; results written into the arrays passed).

Convention: as :mod:`ocalib.calib.stages.refine`: unknowns ordered ``(d, s, dT)`` with ``d`` the local rotation
(``q <- q * (1, d/2) / |.|``), ``x = (dT, s)``, quaternions (w, x, y, z).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ocalib.calib.stages.handeye_kernel import apply_quadratic
from ocalib.calib.stages.linalg_kernel import (
    jit,
    jit_inline,
    left_product_matrix,
    lu_solve,
    quaternion_to_rotation_matrix,
)
from ocalib.calib.stages.refine import REWEIGHT_STEPS
from ocalib.calib.stages.rotation import ROTATION_OBSERVABLE_SIGNIFICANCE
from ocalib.calib.stages.rotation_kernel import excited, rotation_gram

REFINE_CODES = {False: 0, True: 1, "unobservable": 2}  # refine_estimate's mode, for each of refine.REFINE_MODES
_EPS2 = float(np.finfo(np.float64).eps) ** 2


class Workspace(NamedTuple):
    """Scratch arrays of :func:`refine_estimate`."""

    M: np.ndarray  # (4, 4) the rotation system's Gram matrix
    q: np.ndarray  # (4,) the iterate's rotation
    x: np.ndarray  # (4,) and its (dT, s)
    R: np.ndarray  # (3, 3) its rotation matrix
    y: np.ndarray  # (12,) (dT, vec(s dR))
    Py: np.ndarray  # (12,)
    r: np.ndarray  # (12,) the weighted gradient of E_t in y
    H: np.ndarray  # (7, 7) the system
    g: np.ndarray  # (7,)
    d: np.ndarray  # (7,) the step
    L: np.ndarray  # (4, 4)
    Jq: np.ndarray  # (4, 3) dq / dd
    MJ: np.ndarray  # (4, 3)
    Mq: np.ndarray  # (4,) wr M q
    D: np.ndarray  # (3, 3) dR^T times the gradient in s dR
    W: np.ndarray  # (3, 3) dR^T times a row of P[:3, 3:]
    Pw: np.ndarray  # (12, 12) the translation quadratic, each group of rows weighted
    pw: np.ndarray  # (12,)
    wt: np.ndarray  # (2,) the weights of the groups
    Et: np.ndarray  # (2,) their residuals


@jit
def workspace():
    return Workspace(np.empty((4, 4)), np.empty(4), np.empty(4), np.empty((3, 3)), np.empty(12), np.empty(12),
                     np.empty(12), np.empty((7, 7)), np.empty(7), np.empty(7),
                     np.empty((4, 4)), np.empty((4, 3)), np.empty((4, 3)), np.empty(4), np.empty((3, 3)),
                     np.empty((3, 3)), np.empty((12, 12)), np.empty(12), np.empty(2), np.empty(2))  # fmt: skip


@jit
def refine_estimate(est, rotation, quadratic, reverse, translation_rows, mode, steps, flags, work):
    """:func:`~ocalib.calib.stages.refine.refine_estimate` of one entry: ``est`` the closed form
    (:class:`~ocalib.calib.stages.solve_kernel.Estimate`, refined in place where accepted), ``rotation`` the
    :class:`~ocalib.calib.stages.rotation.RotationSystem` and ``quadratic`` ``(P, p, c)`` it came from, ``reverse`` the
    reverse rows' share of it, ``mode`` a code of :data:`REFINE_CODES`, ``flags`` the closed
    form's ``(observable, planar)``. Returns whether it was refined. ``work``: :func:`workspace`."""
    observable, planar = flags
    rows = rotation.rotation_rows
    if mode == 0 or steps == 0:
        return False
    active = excited(est.rotation_singular_values, rows, 1, ROTATION_OBSERVABLE_SIGNIFICANCE) and not planar
    if not (active and translation_rows >= 3 and (mode == 1 or not observable)):
        return False
    rotation_gram(rotation.S2, rotation.V, work.M)
    refined = joint_refine(
        work.M, quadratic, reverse, est.quaternion, est.translation_scale, rows, translation_rows, steps, work
    )
    if refined:
        quaternion_to_rotation_matrix(est.quaternion, est.rotation)
    return refined


@jit
def joint_refine(M, quadratic, reverse, quat, x, rotation_rows, translation_rows, steps, work):
    """:func:`~ocalib.calib.stages.refine.joint_refine` of one active entry: ``quat`` (4,) and ``x`` (4,) the closed
    form, the refined estimate where it is accepted (returned: whether)."""
    q, xr, H, g, d, Jq, wt, Et = work.q, work.x, work.H, work.g, work.d, work.Jq, work.wt, work.Et
    wr, Er0 = _weights(M, quadratic, reverse, quat, x, rotation_rows, translation_rows, work)
    Et0_forward, Et0_reverse = Et[0], Et[1]  # the closed form's residuals
    q[:] = quat
    xr[:] = x
    for step in range(steps + REWEIGHT_STEPS):
        if step == steps:  # the residual variances at the refined estimate
            wr = _weights(M, quadratic, reverse, _canonical(q), xr, rotation_rows, translation_rows, work)[0]
        _system(M, work.Pw, work.pw, q, xr, wr, work)
        if step > 0:
            _newton_terms(q, xr[3], work)
        mean = 0.0
        for i in range(7):
            mean += abs(H[i, i])
        mean = 1e-14 * mean / 7.0
        for i in range(7):
            H[i, i] += mean
            g[i] = -g[i]
        lu_solve(H, g, 7, d)
        for i in range(4):
            q[i] += Jq[i, 0] * d[0] + Jq[i, 1] * d[1] + Jq[i, 2] * d[2]
        nq = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
        for i in range(4):
            q[i] /= nq
        xr[3] += d[3]
        for i in range(3):
            xr[i] += d[4 + i]
    _canonical(q)
    Er = _group_costs(M, quadratic, reverse, q, xr, work)
    ok = wr * Er + wt[0] * Et[0] + wt[1] * Et[1] <= wr * Er0 + wt[0] * Et0_forward + wt[1] * Et0_reverse
    for i in range(4):
        ok = ok and math.isfinite(q[i]) and math.isfinite(xr[i])
    if ok:
        quat[:] = q
        x[:] = xr
    return ok


@jit_inline
def _canonical(q):
    """``q`` on the ``w >= 0`` hemisphere, in place; returns it."""
    if q[0] < 0:
        for i in range(4):
            q[i] = -q[i]
    return q


@jit_inline
def _group_costs(M, quadratic, reverse, q, x, work):
    """:func:`~ocalib.calib.stages.refine.group_costs` at ``(q, x)``: returns the rotation residual ``q^T M q``; the
    forward and the reverse rows' translation residuals in ``work.Et``."""
    (P, p, c), (Pr, pr, cr), R, y, Py = quadratic, reverse, work.R, work.y, work.Py
    quaternion_to_rotation_matrix(q, R)
    for i in range(3):
        y[i] = x[i]
    for i in range(9):
        y[3 + i] = x[3] * R[i // 3, i % 3]
    Er = 0.0
    for i in range(4):
        for j in range(4):
            Er += q[i] * M[i, j] * q[j]
    apply_quadratic(P, y, Py)
    Et = c
    for i in range(12):
        Et += y[i] * (Py[i] - 2.0 * p[i])
    apply_quadratic(Pr, y, Py)
    Etr = cr
    for i in range(12):
        Etr += y[i] * (Py[i] - 2.0 * pr[i])
    work.Et[0], work.Et[1] = Et - Etr, Etr
    return Er


@jit_inline
def _weights(M, quadratic, reverse, q, x, rotation_rows, translation_rows, work):
    """:func:`~ocalib.calib.stages.refine._group_weights` at ``(q, x)``: returns ``1 / sr^2`` and the rotation residual;
    writes each group's ``1 / st^2`` (0 for an empty group) into ``work.wt`` and the translation quadratic weighted by
    them into ``work.Pw``, ``work.pw``."""
    (P, p, c), (Pr, pr, cr), wt, Pw, pw = quadratic, reverse, work.wt, work.Pw, work.pw
    Er = _group_costs(M, quadratic, reverse, q, x, work)
    trace = M[0, 0] + M[1, 1] + M[2, 2] + M[3, 3]
    dof = max(3.0 * translation_rows - 4.0, 1.0)
    n = (1.0 if c - cr > 0 else 0.0) + (1.0 if cr > 0 else 0.0)  # groups with rows
    w0 = dof / max(n * (work.Et[0] + _EPS2 * (c - cr)), 1e-300) if c - cr > 0 else 0.0
    w1 = dof / max(n * (work.Et[1] + _EPS2 * cr), 1e-300) if cr > 0 else 0.0
    wt[0], wt[1] = w0, w1
    for i in range(12):
        pw[i] = w0 * p[i] + (w1 - w0) * pr[i]
        for j in range(12):
            Pw[i, j] = w0 * P[i, j] + (w1 - w0) * Pr[i, j]
    return max(2.0 * rotation_rows - 3.0, 1.0) / max(Er + _EPS2 * trace, 1e-300), Er


@jit_inline
def _system(M, P, p, q, x, wr, work):
    """The Gauss-Newton system of :func:`~ocalib.calib.stages.refine.joint_refine` at ``(q, x)``: ``work.H`` (7, 7) and
    ``work.g`` (7,), and the pieces the Newton terms and the update reuse: ``R = dR``, ``Jq``, ``r``, ``Mq``, ``D``.

    From the blocks of ``P`` rather than the chain rule through ``vec(s dR)`` (the PyTorch stage's ``J_y^T P J_y``):
    ``P``'s lower-right block is ``I (x) Z11`` (``Z11`` = ``P[3:6, 3:6]``), under which
    ``<s dR G_k, s dR G_l Z11> = s^2 (tr(Z11) I - Z11)_kl``, ``<dR G_k, dR Z11> = 0`` and ``<dR, dR Z11> = tr(Z11)``
    whatever ``dR`` (``G_k = [e_k]x``); a row ``i`` of ``P[:3, 3:]`` as a 3x3 ``B_i`` meets ``s dR G_k`` in the
    skew part of ``dR^T B_i``, and the gradient in ``s dR`` (``R_g``) in that of ``D = dR^T R_g``."""
    R, y, r, H, g, L, Jq, MJ, Mq, D, W = (work.R, work.y, work.r, work.H, work.g, work.L, work.Jq, work.MJ, work.Mq,
                                          work.D, work.W)  # fmt: skip
    s = x[3]
    quaternion_to_rotation_matrix(q, R)
    for i in range(3):
        y[i] = x[i]
    for i in range(9):
        y[3 + i] = s * R[i // 3, i % 3]
    apply_quadratic(P, y, r)
    for i in range(12):
        r[i] = r[i] - p[i]
    _rotate_back(R, r, 3, D)  # D = dR^T R_g
    g[0], g[1], g[2], g[3] = s * (D[2, 1] - D[1, 2]), s * (D[0, 2] - D[2, 0]), s * (D[1, 0] - D[0, 1]), (
        D[0, 0] + D[1, 1] + D[2, 2])  # fmt: skip
    trZ = P[3, 3] + P[4, 4] + P[5, 5]
    for k in range(3):
        for l in range(3):
            H[k, l] = s * s * ((trZ if k == l else 0.0) - P[3 + k, 3 + l])
        H[k, 3] = H[3, k] = 0.0
    H[3, 3] = trZ
    for i in range(3):
        _rotate_back(R, P[i], 3, W)  # W = dR^T B_i
        H[4 + i, 0], H[4 + i, 1], H[4 + i, 2] = (
            s * (W[2, 1] - W[1, 2]),
            s * (W[0, 2] - W[2, 0]),
            s * (W[1, 0] - W[0, 1]),
        )
        H[4 + i, 3] = W[0, 0] + W[1, 1] + W[2, 2]
        for j in range(4):
            H[j, 4 + i] = H[4 + i, j]
        for j in range(3):
            H[4 + i, 4 + j] = P[i, j]
        g[4 + i] = r[i]
    left_product_matrix(q, L)
    for i in range(4):
        for j in range(3):
            Jq[i, j] = 0.5 * L[i, 1 + j]
        Mq[i] = wr * (M[i, 0] * q[0] + M[i, 1] * q[1] + M[i, 2] * q[2] + M[i, 3] * q[3])
    for i in range(4):
        for b in range(3):
            MJ[i, b] = M[i, 0] * Jq[0, b] + M[i, 1] * Jq[1, b] + M[i, 2] * Jq[2, b] + M[i, 3] * Jq[3, b]
    for a in range(3):
        for b in range(3):
            H[a, b] += wr * (Jq[0, a] * MJ[0, b] + Jq[1, a] * MJ[1, b] + Jq[2, a] * MJ[2, b] + Jq[3, a] * MJ[3, b])
        g[a] += Jq[0, a] * Mq[0] + Jq[1, a] * Mq[1] + Jq[2, a] * Mq[2] + Jq[3, a] * Mq[3]


@jit_inline
def _rotate_back(R, v, offset, out):
    """``out = R^T B`` (3x3) with ``B[r, j] = v[offset + 3 r + j]``."""
    for i in range(3):
        for j in range(3):
            out[i, j] = R[0, i] * v[offset + j] + R[1, i] * v[offset + 3 + j] + R[2, i] * v[offset + 6 + j]


@jit_inline
def _newton_terms(q, s, work):
    """Add Newton's second-derivative terms to ``work.H``: those of ``m = vec(s dR)`` and of ``q``, contracted with the
    gradient (``_system``'s ``r`` and ``Mq``)."""
    H, Mq, D = work.H, work.Mq, work.D  # D = dR^T R_g, R_g the gradient in s dR (from _system)
    qMq = Mq[0] * q[0] + Mq[1] * q[1] + Mq[2] * q[2] + Mq[3] * q[3]
    trD = D[0, 0] + D[1, 1] + D[2, 2]
    for k in range(3):  # <D, (G_k G_l + G_l G_k) / 2> with G_k G_l = e_l e_k^T - delta_kl I
        for l in range(3):
            H[k, l] += s * (0.5 * (D[l, k] + D[k, l]) - (trD if k == l else 0.0))
        H[k, k] -= 0.25 * qMq
    for k, dG in enumerate((D[2, 1] - D[1, 2], D[0, 2] - D[2, 0], D[1, 0] - D[0, 1])):  # <D, G_k>
        H[k, 3] += dG
        H[3, k] += dG
