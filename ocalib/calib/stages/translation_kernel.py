"""Compiled twins (numba) of :mod:`ocalib.calib.stages.translation`: the exact translation solve and the scale fit, for
one entry (no batch dimension; results written into the arrays passed).

Convention: as :mod:`ocalib.calib.stages.translation`: ``x = (dT, s)``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ocalib.calib.stages.handeye_kernel import normal_equations
from ocalib.calib.stages.linalg_kernel import eigh, jit
from ocalib.calib.stages.translation import RANK_TOLERANCE, SCALE_FITS, UNOBSERVABLE_RELATIVE

SCALE_FIT_CODES = {name: code for code, name in enumerate(SCALE_FITS)}  # fit_scale's mode
SYMMETRIC = SCALE_FIT_CODES["symmetric"]


class Workspace(NamedTuple):
    """Scratch arrays of the solves of a system of up to 6 unknowns."""

    maps: np.ndarray  # (3, 3, 3) the maps of normal_equations
    H: np.ndarray  # (6, 6)
    g: np.ndarray  # (6,)
    evals: np.ndarray  # (6,)
    evecs: np.ndarray  # (6, 6)
    jacobi: np.ndarray  # (6, 6)
    u: np.ndarray  # (3,) symmetric_scale's H_TT^-1 h_Ts
    v: np.ndarray  # (3,) and H_TT^-1 g_T


@jit
def workspace():
    return Workspace(np.empty((3, 3, 3)), np.empty((6, 6)), np.empty(6), np.empty(6), np.empty((6, 6)),
                     np.empty((6, 6)), np.empty(3), np.empty(3))  # fmt: skip


@jit
def solve_translation(quadratic, dR, x, work):
    """:func:`~ocalib.calib.stages.translation.solve_translation`: ``x = (dT, s)`` (4,) written, from the moment's
    ``quadratic`` ``(P, p, c)`` and the rotation ``dR`` (3, 3). ``work``: :func:`workspace`."""
    work.maps[0] = dR
    normal_equations(quadratic, work.maps, 1, work.H, work.g)
    spd_solve(work.H, work.g, 4, x, work)


@jit
def fit_scale(est, quadratic, mode, work):
    """:func:`~ocalib.calib.stages.translation.fit_scale`: ``est`` (:class:`~ocalib.calib.stages.solve_kernel.Estimate`)
    has its translation and scale re-fitted in place where ``mode`` (a code of :data:`SCALE_FIT_CODES`) is the symmetric
    fit. ``work``: :func:`workspace`."""
    if mode != SYMMETRIC:
        return
    x, axis = est.translation_scale, est.planar_axis
    work.maps[0] = est.rotation
    normal_equations(quadratic, work.maps, 1, work.H, work.g)
    symmetric_scale(work.H, work.g, quadratic[2], x, work)
    along = axis[0] * x[0] + axis[1] * x[1] + axis[2] * x[2]  # minimum_norm
    for i in range(3):
        x[i] -= axis[i] * along


@jit
def symmetric_scale(H, g, c, x, work):
    """:func:`~ocalib.calib.stages.translation.symmetric_scale` of the normal equations ``H`` (4x4 block), ``g`` (4),
    ``c``: ``x`` (4) updated where the scale is observable. ``work``: :func:`workspace` (``H`` and ``g`` may be its
    own)."""
    u, v = work.u, work.v
    spd_solve(H, H[:, 3], 3, u, work)
    spd_solve(H, g, 3, v, work)
    A, B, C = H[3, 3], g[3], c
    for i in range(3):
        A -= H[i, 3] * u[i]
        B -= H[i, 3] * v[i]
        C -= g[i] * v[i]
    if not A > UNOBSERVABLE_RELATIVE * H[3, 3]:
        return
    s = math.sqrt(max(C, 0.0) / A)
    s = s if B > 0.0 else (-s if B < 0.0 else 0.0)
    fitted = math.isfinite(s)
    for i in range(3):
        fitted = fitted and math.isfinite(v[i] - u[i] * s)
    if fitted:
        for i in range(3):
            x[i] = v[i] - u[i] * s
        x[3] = s


@jit
def pinv_solve(H, g, n, x, work):
    """:func:`~ocalib.calib.stages.translation.pinv_solve`: the minimum-norm ``x`` with ``H x = g`` (symmetric PSD n x n
    block; n <= 6) written. ``work``: :func:`workspace` (its eigen-decomposition arrays)."""
    w, V = work.evals, work.evecs
    eigh(H, n, w, V, work.jacobi)
    cut = RANK_TOLERANCE * max(w[n - 1], 1e-300)
    for i in range(n):
        x[i] = 0.0
    for k in range(n):
        if w[k] > cut:
            c = 0.0
            for i in range(n):
                c += V[i, k] * g[i]
            c /= w[k]
            for i in range(n):
                x[i] += c * V[i, k]


@jit
def spd_solve(H, g, n, x, work):
    """:func:`pinv_solve` by Cholesky where that is the same solution: ``H`` positive definite with
    ``trace(H) trace(H^-1) < 1 / RANK_TOLERANCE``, a bound on its condition number, so that no eigenvalue would
    be cut. Elsewhere the eigen-decomposition's pseudo-inverse."""
    Lc, y, Linv = work.jacobi, work.evals, work.evecs  # the Cholesky factor (lower), L^-1 g, L^-1
    for j in range(n):
        d = H[j, j]
        for k in range(j):
            d -= Lc[j, k] * Lc[j, k]
        if not d > 0.0:
            pinv_solve(H, g, n, x, work)
            return
        d = math.sqrt(d)
        Lc[j, j] = d
        for i in range(j + 1, n):
            acc = H[i, j]
            for k in range(j):
                acc -= Lc[i, k] * Lc[j, k]
            Lc[i, j] = acc / d
    for i in range(n):
        acc = g[i]
        for k in range(i):
            acc -= Lc[i, k] * y[k]
        y[i] = acc / Lc[i, i]
    trace_inv, trace = 0.0, 0.0  # trace(H^-1) = |L^-1|_F^2
    for j in range(n):
        trace += H[j, j]
        for i in range(n):
            if i < j:
                Linv[i, j] = 0.0
                continue
            acc = 1.0 if i == j else 0.0
            for k in range(j, i):
                acc -= Lc[i, k] * Linv[k, j]
            Linv[i, j] = acc / Lc[i, i]
            trace_inv += Linv[i, j] * Linv[i, j]
    if not trace * trace_inv * RANK_TOLERANCE < 1.0:
        pinv_solve(H, g, n, x, work)
        return
    for i in range(n - 1, -1, -1):  # x = L^-T y
        acc = y[i]
        for k in range(i + 1, n):
            acc -= Lc[k, i] * x[k]
        x[i] = acc / Lc[i, i]
