"""The streaming head's frame update as a compiled CPU kernel (numba): the same equations, without PyTorch's
per-operation dispatch.

:class:`~ocalib.calib.online.OnlineCalibrator` spends its CPU time dispatching about 900 small tensor operations
a frame (about 2 us each), not computing: the paper's equations alone take 200 us a frame in eager PyTorch. This
module runs one frame of the head -- pose checks, motion pairing, screw gate, robust weights, incremental SVD of
each gap, the gaps' noise weights, the closed-form estimate (planar route included), the exact translation solve
and the joint refinement -- for every rig in compiled loops over 4x4 to 15x15 matrices, in float64, updating the
module's buffers in place (``state_dict`` is unchanged). From ``PARALLEL_MIN_RIGS`` rigs up, rigs run in parallel over
numba's threads.

It is a second implementation of :mod:`ocalib.calib.online` and its helpers (``gating``, ``pairing``,
``handeye``, ``rotation``, ``translation``, ``planar``, ``solve``, ``refine``) and follows them line by line; the
tests hold the two equal frame by frame. Small symmetric eigenproblems are solved by cyclic Jacobi (eigenvalues
ascending, as ``torch.linalg.eigh``), the refinement's 7x7 systems by LU with partial pivoting. Where an
eigenvalue is repeated (a rotation system that is not yet excited) the eigenvectors differ from LAPACK's by a
rotation within the repeated space; everything the head reports is invariant to that except the null vector of
an unobservable rotation and the sign of the planar axis. Where a system is rank-deficient (the planar route on
fewer than 3 motion pairs), rounding can decide which eigenvalues the pseudo-inverse cuts, and the two minimum-norm
solutions differ.

Scope: CPU, float64, ``solver="exact"``, no gradients. Everything else runs the PyTorch head.

Convention: as :mod:`ocalib.calib.online`: poses camera-to-world, ``T_cam0_camk``, quaternions (w, x, y, z).
"""

from __future__ import annotations

import math
import sys

import numba
import numpy as np
import torch
from numba import njit, prange
from torch import Tensor

from ocalib.calib.gating import MAD_TO_STD, SCREW_MAX_SAMPLES, SCREW_MIN_SAMPLES
from ocalib.calib.pairing import GAP_PRIOR_DOF, GAP_WEIGHT_POWER, NOISE_FLOOR
from ocalib.calib.rotation import PLANAR_SIGNIFICANCE, ROTATION_OBSERVABLE_MIN_SV, ROTATION_OBSERVABLE_SIGNIFICANCE
from ocalib.calib.translation import RANK_TOLERANCE

PARALLEL_MIN_RIGS = 16  # fewer rigs run on the calling thread (starting the thread pool costs more)
REFINE_CODES = {False: 0, True: 1, "unobservable": 2}
# The head's buffers the kernel reads and updates, in the order of its ``state`` tuple (after the poses).
STATE = (
    "history",
    "history_valid",
    "first",
    "first_valid",
    "gap_S2",
    "gap_V",
    "gap_rotation_rows",
    "gap_Z",
    "gap_translation_rows",
    "S2",
    "V",
    "rotation_rows",
    "screw_scale",
    "screw_count",
    "frames_used",
    "frames_rejected",
)
JACOBI_SWEEPS = 30
JACOBI_TOLERANCE = 1e-16  # an off-diagonal entry below this times sqrt(a_pp a_qq) is treated as zero
_EPS2 = float(np.finfo(np.float64).eps) ** 2


_jit = njit(cache=True, nogil=True, error_model="numpy", fastmath={"contract", "reassoc"})


# ---------------------------------------------------------------------------------------------- small algebra
@_jit
def _eigh(A, n, w, V, a):
    """Eigen-decomposition of the symmetric n x n block of ``A`` by cyclic Jacobi: ``w`` ascending, ``V`` its
    eigenvectors as columns (both written), ``a`` scratch (n x n at least)."""
    for i in range(n):
        for j in range(n):
            a[i, j] = A[i, j]
            V[i, j] = 1.0 if i == j else 0.0
    for _ in range(JACOBI_SWEEPS):
        rotated = False
        for p in range(n):
            for q in range(p + 1, n):
                c, s, t = _rotation(a, p, q)
                if s != 0.0:
                    _rotate(a, V, p, q, c, s, t, n)
                    rotated = True
        if not rotated:
            break
    _sort(w, V, a, n)


@_jit
def _rotation(a, p, q):
    """Jacobi rotation ``(c, s, t)`` that zeroes ``a[p, q]``; ``(1, 0, 0)`` where it is negligible (it moves no
    eigenvalue by more than its rounding: relative accuracy, as LAPACK's)."""
    apq = a[p, q]
    if apq * apq <= JACOBI_TOLERANCE * JACOBI_TOLERANCE * abs(a[p, p] * a[q, q]):
        return 1.0, 0.0, 0.0
    theta = (a[q, q] - a[p, p]) / (2.0 * apq)
    t = 1.0 / (abs(theta) + math.sqrt(theta * theta + 1.0))
    if theta < 0.0:
        t = -t
    c = 1.0 / math.sqrt(t * t + 1.0)
    return c, t * c, t


@_jit
def _rotate(a, V, p, q, c, s, t, n):
    """Apply the rotation of :func:`_rotation` to the symmetric ``a`` and the eigenvectors ``V``."""
    apq = a[p, q]
    a[p, p] -= t * apq
    a[q, q] += t * apq
    a[p, q] = a[q, p] = 0.0
    for r in range(n):
        if r != p and r != q:
            arp, arq = a[r, p], a[r, q]
            a[r, p] = a[p, r] = c * arp - s * arq
            a[r, q] = a[q, r] = s * arp + c * arq
    for k in range(n):
        vkp, vkq = V[k, p], V[k, q]
        V[k, p], V[k, q] = c * vkp - s * vkq, s * vkp + c * vkq


@_jit
def _eigh4(A, w, V, a):
    """:func:`_eigh` of a 4x4 matrix, in rounds of two disjoint rotations ((0, 1) and (2, 3), then (0, 2) and
    (1, 3), then (0, 3) and (1, 2)): the two of a round are independent, so their square roots and divisions
    overlap (a rotation's cost is their latency)."""
    for i in range(4):
        for j in range(4):
            a[i, j] = A[i, j]
            V[i, j] = 1.0 if i == j else 0.0
    for _ in range(JACOBI_SWEEPS):
        rotated = False
        for r in range(3):
            p1, q1, p2, q2 = (0, 1, 2, 3) if r == 0 else ((0, 2, 1, 3) if r == 1 else (0, 3, 1, 2))
            c1, s1, t1 = _rotation(a, p1, q1)
            c2, s2, t2 = _rotation(a, p2, q2)
            if s1 != 0.0:
                _rotate(a, V, p1, q1, c1, s1, t1, 4)
                rotated = True
            if s2 != 0.0:
                _rotate(a, V, p2, q2, c2, s2, t2, 4)
                rotated = True
        if not rotated:
            break
    _sort(w, V, a, 4)


@_jit
def _sort(w, V, a, n):
    """Eigenvalues ``w`` from the diagonal of ``a``, ascending, with the columns of ``V`` (insertion sort, stable)."""
    for i in range(n):
        w[i] = a[i, i]
    for i in range(1, n):
        j = i
        while j > 0 and w[j - 1] > w[j]:
            w[j - 1], w[j] = w[j], w[j - 1]
            for k in range(n):
                V[k, j - 1], V[k, j] = V[k, j], V[k, j - 1]
            j -= 1


@_jit
def _pinv_solve(H, g, n, x, w, V, a):
    """Minimum-norm solution ``x`` of ``H x = g`` (symmetric PSD n x n), as :func:`~ocalib.calib.translation.pinv_solve`."""
    _eigh(H, n, w, V, a)
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


@_jit
def _spd_solve(H, g, n, x, w, V, a):
    """:func:`_pinv_solve` by Cholesky where that is the same solution: ``H`` positive definite with
    ``trace(H) trace(H^-1) < 1 / RANK_TOLERANCE``, a bound on its condition number, so that no eigenvalue would
    be cut. Elsewhere the eigen-decomposition's pseudo-inverse."""
    Lc = a  # the Cholesky factor (lower), then its inverse
    for j in range(n):
        d = H[j, j]
        for k in range(j):
            d -= Lc[j, k] * Lc[j, k]
        if not d > 0.0:
            _pinv_solve(H, g, n, x, w, V, a)
            return
        d = math.sqrt(d)
        Lc[j, j] = d
        for i in range(j + 1, n):
            acc = H[i, j]
            for k in range(j):
                acc -= Lc[i, k] * Lc[j, k]
            Lc[i, j] = acc / d
    for i in range(n):  # y = L^-1 g, and the columns of L^-1 (into V) for trace(H^-1) = |L^-1|_F^2
        acc = g[i]
        for k in range(i):
            acc -= Lc[i, k] * w[k]
        w[i] = acc / Lc[i, i]
    trace_inv, trace = 0.0, 0.0
    for j in range(n):
        trace += H[j, j]
        for i in range(n):
            if i < j:
                V[i, j] = 0.0
                continue
            acc = 1.0 if i == j else 0.0
            for k in range(j, i):
                acc -= Lc[i, k] * V[k, j]
            V[i, j] = acc / Lc[i, i]
            trace_inv += V[i, j] * V[i, j]
    if not trace * trace_inv * RANK_TOLERANCE < 1.0:
        _pinv_solve(H, g, n, x, w, V, a)
        return
    for i in range(n - 1, -1, -1):  # x = L^-T y
        acc = w[i]
        for k in range(i + 1, n):
            acc -= Lc[k, i] * x[k]
        x[i] = acc / Lc[i, i]


@_jit
def _lu_solve(H, b, n, x):
    """Solve ``H x = b`` (n x n) by LU with partial pivoting; ``H`` and ``b`` are overwritten."""
    for j in range(n):
        p = j
        for i in range(j + 1, n):
            if abs(H[i, j]) > abs(H[p, j]):
                p = i
        if p != j:
            for k in range(n):
                H[j, k], H[p, k] = H[p, k], H[j, k]
            b[j], b[p] = b[p], b[j]
        for i in range(j + 1, n):
            f = H[i, j] / H[j, j]
            for k in range(j + 1, n):
                H[i, k] -= f * H[j, k]
            b[i] -= f * b[j]
    for i in range(n - 1, -1, -1):
        s = b[i]
        for k in range(i + 1, n):
            s -= H[i, k] * x[k]
        x[i] = s / H[i, i]


@_jit
def _quat_to_rot(q, R):
    """Rotation matrix ``R`` (3x3) of the quaternion ``q`` (any norm > 0)."""
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    w, x, y, z = q[0] / n, q[1] / n, q[2] / n, q[3] / n
    R[0, 0] = w * w + x * x - y * y - z * z
    R[0, 1] = 2.0 * (x * y - w * z)
    R[0, 2] = 2.0 * (x * z + w * y)
    R[1, 0] = 2.0 * (x * y + w * z)
    R[1, 1] = w * w - x * x + y * y - z * z
    R[1, 2] = 2.0 * (y * z - w * x)
    R[2, 0] = 2.0 * (x * z - w * y)
    R[2, 1] = 2.0 * (y * z + w * x)
    R[2, 2] = w * w - x * x - y * y + z * z


@_jit
def _rot_to_quat(R, q):
    """Shepperd's method, as :func:`~ocalib.geometry.quaternion.rotation_matrix_to_quaternion` (w >= 0)."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = (R[0, 0], R[0, 1], R[0, 2], R[1, 0], R[1, 1], R[1, 2],
                                                   R[2, 0], R[2, 1], R[2, 2])  # fmt: skip
    d0, d1, d2, d3 = 1 + r00 + r11 + r22, 1 + r00 - r11 - r22, 1 - r00 + r11 - r22, 1 - r00 - r11 + r22
    best = d0
    pivot = 0
    if d1 > best:
        best, pivot = d1, 1
    if d2 > best:
        best, pivot = d2, 2
    if d3 > best:
        pivot = 3
    if pivot == 0:
        a, b, c, d = d0, r21 - r12, r02 - r20, r10 - r01
    elif pivot == 1:
        a, b, c, d = r21 - r12, d1, r01 + r10, r02 + r20
    elif pivot == 2:
        a, b, c, d = r02 - r20, r01 + r10, d2, r12 + r21
    else:
        a, b, c, d = r10 - r01, r02 + r20, r12 + r21, d3
    n = math.sqrt(a * a + b * b + c * c + d * d)
    if a < 0:
        n = -n
    q[0], q[1], q[2], q[3] = a / n, b / n, c / n, d / n


@_jit
def _excited(S, rows, i, significance):
    """:func:`~ocalib.calib.rotation.excited` of singular values ``S`` (4)."""
    floor = S[3] * S[3]
    excess = (S[i] * S[i] - floor) * math.sqrt(max(2.0 * rows - 3.0, 1.0))
    return S[i] > ROTATION_OBSERVABLE_MIN_SV and excess > significance * floor


@_jit
def _quadratic(Z, P, p):
    """:func:`~ocalib.calib.handeye.translation_quadratic`: P (12x12), p (12) written, c returned."""
    for i in range(12):
        for j in range(12):
            P[i, j] = 0.0
    for i in range(3):
        for j in range(3):
            P[i, j] = Z[i, j] + Z[3 + i, 3 + j] + Z[6 + i, 6 + j]
        for r in range(3):
            for j in range(3):
                P[i, 3 + 3 * r + j] = Z[3 * r + i, 9 + j]
                P[3 + 3 * r + j, i] = Z[3 * r + i, 9 + j]
    for a in range(3):
        for b in range(3):
            for d in range(3):
                P[3 + 3 * a + b, 3 + 3 * a + d] = Z[9 + b, 9 + d]
    for i in range(3):
        s = 0.0
        for r in range(3):
            s += Z[3 * r + i, 12 + r]
        p[i] = s
    for r in range(3):
        for j in range(3):
            p[3 + 3 * r + j] = Z[9 + j, 12 + r]
    return Z[12, 12] + Z[13, 13] + Z[14, 14]


@_jit
def _normal_equations(P, p, maps, m, H, g):
    """:func:`~ocalib.calib.handeye.normal_equations` for ``m`` maps (m, 3, 3): H (3+m)^2 and g written."""
    for a in range(3):
        g[a] = p[a]
        for b in range(3):
            H[a, b] = P[a, b]
    for k in range(m):
        s = 0.0
        for i in range(9):
            s += maps[k, i // 3, i % 3] * p[3 + i]
        g[3 + k] = s
        for a in range(3):
            s = 0.0
            for i in range(9):
                s += P[a, 3 + i] * maps[k, i // 3, i % 3]
            H[a, 3 + k] = s
            H[3 + k, a] = s
        for l in range(m):
            s = 0.0
            for i in range(9):
                li = maps[k, i // 3, i % 3]
                if li == 0.0:
                    continue
                for j in range(9):
                    s += li * P[3 + i, 3 + j] * maps[l, j // 3, j % 3]
            H[3 + k, 3 + l] = s


@_jit
def _apply_P(P, y, out):
    """``out = P y`` for the translation quadratic's ``P`` (12x12), whose lower-right block is ``I (x) Z_t1t1``."""
    for i in range(3):
        acc = 0.0
        for j in range(12):
            acc += P[i, j] * y[j]
        out[i] = acc
    for a in range(3):
        for b in range(3):
            i = 3 + 3 * a + b
            out[i] = (P[i, 0] * y[0] + P[i, 1] * y[1] + P[i, 2] * y[2]
                      + P[i, 3 + 3 * a] * y[3 + 3 * a] + P[i, 4 + 3 * a] * y[4 + 3 * a] + P[i, 5 + 3 * a] * y[5 + 3 * a])  # fmt: skip


@_jit
def _costs(M, P, p, c, q, x, R, y, Py):
    """:func:`~ocalib.calib.refine.costs`: (Er, Et) at ``(q, x)``; ``R`` (3x3), ``y`` and ``Py`` (12) scratch."""
    _quat_to_rot(q, R)
    for i in range(3):
        y[i] = x[i]
    for i in range(9):
        y[3 + i] = x[3] * R[i // 3, i % 3]
    Er = 0.0
    for i in range(4):
        for j in range(4):
            Er += q[i] * M[i, j] * q[j]
    _apply_P(P, y, Py)
    Et = c
    for i in range(12):
        Et += y[i] * (Py[i] - 2.0 * p[i])
    return Er, Et


@_jit
def _left(q, L):
    """``L(q)`` (4x4): ``q * p = L(q) p``."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    L[0, 0], L[0, 1], L[0, 2], L[0, 3] = w, -x, -y, -z
    L[1, 0], L[1, 1], L[1, 2], L[1, 3] = x, w, -z, y
    L[2, 0], L[2, 1], L[2, 2], L[2, 3] = y, z, w, -x
    L[3, 0], L[3, 1], L[3, 2], L[3, 3] = z, -y, x, w


@_jit
def _refine_workspace():
    """Scratch arrays of :func:`_joint_refine` (allocated once per thread, not per rig)."""
    return (np.empty((3, 3)), np.empty(12), np.empty((9, 4)), np.empty(12), np.empty((12, 7)), np.empty((7, 7)),
            np.empty(7), np.empty(7), np.empty((4, 3)), np.empty((4, 3)), np.empty((4, 4)), np.empty(4),
            np.empty((3, 3)), np.empty(4), np.empty(3), np.empty(4), np.empty(12))  # fmt: skip


@_jit
def _joint_refine(M, P, p, c, quat, x, rotation_rows, translation_rows, steps, out_q, out_x, work):
    """:func:`~ocalib.calib.refine.joint_refine` for one entry (active): writes ``out_q``, ``out_x`` and returns
    whether the refined estimate was accepted. ``work``: :func:`_refine_workspace`."""
    R, y, C, r, K, H, g, d, Jq, MJ, L, Mq, D, q, dT, xr, Py = work
    Er0, Et0 = _costs(M, P, p, c, quat, x, R, y, Py)
    trace = M[0, 0] + M[1, 1] + M[2, 2] + M[3, 3]
    wr = max(2.0 * rotation_rows - 3.0, 1.0) / max(Er0 + _EPS2 * trace, 1e-300)
    wt = max(3.0 * translation_rows - 4.0, 1.0) / max(Et0 + _EPS2 * c, 1e-300)
    q[:] = quat
    s = x[3]
    dT[:] = x[:3]
    for step in range(steps):
        # _system: the Gauss-Newton system at (q, s, dT), unknowns (d, s, dT).
        _quat_to_rot(q, R)
        for i in range(3):  # C[:, k] = s vec(dR [e_k]x): dR [e_k]x = [0, R2, -R1], [-R2, 0, R0], [R1, -R0, 0]
            C[3 * i, 0], C[3 * i + 1, 0], C[3 * i + 2, 0] = 0.0, s * R[i, 2], -s * R[i, 1]
            C[3 * i, 1], C[3 * i + 1, 1], C[3 * i + 2, 1] = -s * R[i, 2], 0.0, s * R[i, 0]
            C[3 * i, 2], C[3 * i + 1, 2], C[3 * i + 2, 2] = s * R[i, 1], -s * R[i, 0], 0.0
        for i in range(9):
            C[i, 3] = R[i // 3, i % 3]
        for i in range(3):
            y[i] = dT[i]
        for i in range(9):
            y[3 + i] = s * R[i // 3, i % 3]
        _apply_P(P, y, r)
        for i in range(12):
            r[i] = wt * (r[i] - p[i])
        for i in range(12):  # K = P J_y: [P[:, 3:] C, P[:, :3]], P[3:, 3:] block diagonal
            lo, hi = (0, 9) if i < 3 else (3 * ((i - 3) // 3), 3 * ((i - 3) // 3) + 3)
            for j in range(4):
                acc = 0.0
                for k in range(lo, hi):
                    acc += P[i, 3 + k] * C[k, j]
                K[i, j] = acc
            for j in range(3):
                K[i, 4 + j] = P[i, j]
        for i in range(4):
            for j in range(7):
                acc = 0.0
                for k in range(9):
                    acc += C[k, i] * K[3 + k, j]
                H[i, j] = wt * acc
            acc = 0.0
            for k in range(9):
                acc += C[k, i] * r[3 + k]
            g[i] = acc
        for i in range(3):
            for j in range(7):
                H[4 + i, j] = wt * K[i, j]
            g[4 + i] = r[i]
        _left(q, L)
        for i in range(4):
            for j in range(3):
                Jq[i, j] = 0.5 * L[i, 1 + j]
        for i in range(4):
            acc = 0.0
            for j in range(4):
                acc += M[i, j] * q[j]
            Mq[i] = wr * acc
        for i in range(4):
            for b in range(3):
                MJ[i, b] = M[i, 0] * Jq[0, b] + M[i, 1] * Jq[1, b] + M[i, 2] * Jq[2, b] + M[i, 3] * Jq[3, b]
        for a in range(3):
            for b in range(3):
                acc = Jq[0, a] * MJ[0, b] + Jq[1, a] * MJ[1, b] + Jq[2, a] * MJ[2, b] + Jq[3, a] * MJ[3, b]
                H[a, b] += wr * acc
            acc = 0.0
            for i in range(4):
                acc += Jq[i, a] * Mq[i]
            g[a] += acc
        if step > 0:  # Newton: second derivatives of m and q, contracted with the gradient
            for i in range(3):
                for j in range(3):  # D = dR^T R, R the gradient in s dR
                    D[i, j] = R[0, i] * r[3 + j] + R[1, i] * r[6 + j] + R[2, i] * r[9 + j]
            qMq = Mq[0] * q[0] + Mq[1] * q[1] + Mq[2] * q[2] + Mq[3] * q[3]
            trD = D[0, 0] + D[1, 1] + D[2, 2]
            for k in range(3):  # <D, (G_k G_l + G_l G_k) / 2> with G_k G_l = e_l e_k^T - delta_kl I
                for l in range(3):
                    H[k, l] += s * (0.5 * (D[l, k] + D[k, l]) - (trD if k == l else 0.0))
                H[k, k] -= 0.25 * qMq
            for k, dG in enumerate((D[2, 1] - D[1, 2], D[0, 2] - D[2, 0], D[1, 0] - D[0, 1])):  # <D, G_k>
                H[k, 3] += dG
                H[3, k] += dG
        mean = 0.0
        for i in range(7):
            mean += abs(H[i, i])
        mean = 1e-14 * mean / 7.0
        for i in range(7):
            H[i, i] += mean
            g[i] = -g[i]
        _lu_solve(H, g, 7, d)
        for i in range(4):
            q[i] += Jq[i, 0] * d[0] + Jq[i, 1] * d[1] + Jq[i, 2] * d[2]
        nq = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
        for i in range(4):
            q[i] /= nq
        s += d[3]
        for i in range(3):
            dT[i] += d[4 + i]
    if q[0] < 0:
        for i in range(4):
            q[i] = -q[i]
    xr[:3] = dT
    xr[3] = s
    Er, Et = _costs(M, P, p, c, q, xr, R, y, Py)
    ok = wr * Er + wt * Et <= wr * Er0 + wt * Et0
    for i in range(4):
        ok = ok and math.isfinite(q[i]) and math.isfinite(xr[i])
    if ok:
        out_q[:] = q
        out_x[:] = xr
    return ok


# --------------------------------------------------------------------------------------------- one rig, one frame
@_jit
def _workspace(C, n_pairs):
    """Scratch arrays of :func:`_rig_step` for C cameras and ``n_pairs`` motion pairs (once per thread)."""
    return (np.empty((C, 4, 4)), np.empty(C, dtype=np.bool_), np.empty((C, n_pairs, 4, 4)),
            np.empty((C, n_pairs), dtype=np.bool_), np.empty((4, 4)), np.empty((C, n_pairs, 4)),
            np.empty((C, n_pairs)), np.empty((4, 4)), np.empty((4, 4)), np.empty((4, 4)), np.empty(4),
            np.empty((4, 4)), np.empty((7, 7)), np.empty((7, 7)), np.empty(7), np.empty((4, 4)), np.empty((2, 15)),
            np.empty(n_pairs, dtype=np.bool_), np.empty(n_pairs), np.empty((4, 4)), np.empty(4),
            np.empty(4), np.empty((3, 3)), np.empty((12, 12)), np.empty(12), np.empty((3, 3, 3)), np.empty((6, 6)),
            np.empty(6), np.empty(6), np.empty(4), np.empty(3), np.empty(4), np.empty(4), _refine_workspace())  # fmt: skip


@_jit
def _read_poses(poses, b, pose, valid, pose_tolerance):
    """Rig ``b``'s poses into ``pose`` (C, 4, 4); a non-finite or non-orthonormal pose is replaced by the identity and
    marked invalid in ``valid`` (C,)."""
    C = poses.shape[1]
    for cam in range(C):
        ok = True
        for i in range(4):
            for j in range(4):
                v = poses[b, cam, i, j]
                pose[cam, i, j] = v
                ok = ok and math.isfinite(v)
        if ok:
            err = 0.0
            for i in range(3):
                for j in range(3):
                    acc = 0.0
                    for k in range(3):
                        acc += pose[cam, k, i] * pose[cam, k, j]
                    err = max(err, abs(acc - (1.0 if i == j else 0.0)))
            det = ((pose[cam, 0, 1] * pose[cam, 1, 2] - pose[cam, 0, 2] * pose[cam, 1, 1]) * pose[cam, 2, 0]
                   + (pose[cam, 0, 2] * pose[cam, 1, 0] - pose[cam, 0, 0] * pose[cam, 1, 2]) * pose[cam, 2, 1]
                   + (pose[cam, 0, 0] * pose[cam, 1, 1] - pose[cam, 0, 1] * pose[cam, 1, 0]) * pose[cam, 2, 2])  # fmt: skip
            ok = max(err, abs(det - 1.0)) < pose_tolerance
        valid[cam] = ok
        if not ok:
            for i in range(4):
                for j in range(4):
                    pose[cam, i, j] = 1.0 if i == j else 0.0


@_jit
def _motion_pairs(
    b,
    pose,
    valid,
    history,
    history_valid,
    first,
    first_valid,
    gaps,
    has_first,
    frame,
    motion,
    prev,
    prev_valid,
    quat,
    angle,
):
    """Every camera's motion pairs (C, n_pairs, 4, 4) ``inv(earlier) @ pose``: gap g from frame t - g, then the pair
    with the first valid frame (kept in ``first``); their quaternions ``quat`` (w, x, y, z) and angles ``angle``."""
    C = pose.shape[0]
    H_size = history.shape[2]
    n_pos = gaps.shape[0]
    n_pairs = n_pos + (1 if has_first else 0)
    for j in range(n_pairs):
        for cam in range(C):
            if j < n_pos:
                slot = (frame - gaps[j]) % H_size
                prev[:, :] = history[b, cam, slot]
                prev_valid[cam, j] = history_valid[b, cam, slot]
            else:
                prev[:, :] = first[b, cam]
                prev_valid[cam, j] = first_valid[b]
            for i in range(3):  # inv(prev) @ pose
                for k in range(4):
                    acc = 0.0
                    for m in range(3):
                        acc += prev[m, i] * (pose[cam, m, k] - (prev[m, 3] if k == 3 else 0.0))
                    motion[cam, j, i, k] = acc
            motion[cam, j, 3, 0], motion[cam, j, 3, 1], motion[cam, j, 3, 2], motion[cam, j, 3, 3] = 0.0, 0.0, 0.0, 1.0
    if has_first:
        start = not first_valid[b]
        for cam in range(C):
            start = start and valid[cam]
        if start:
            first[b] = pose
            first_valid[b] = True

    for cam in range(C):
        for j in range(n_pairs):
            _rot_to_quat(motion[cam, j], quat[cam, j])
            qv = quat[cam, j]
            angle[cam, j] = 2.0 * math.atan2(math.sqrt(qv[1] * qv[1] + qv[2] * qv[2] + qv[3] * qv[3]), abs(qv[0]))


@_jit
def _screw_gate(b, k, n_pairs, valid, prev_valid, angle, screw_scale, screw_count, screw_sigma, screw_gate, pair_ok):
    """Screw congruence of camera k + 1 against camera 0: ``pair_ok`` (n_pairs,) for the pairs whose rotation angles
    agree within the robust threshold; updates the running scale of the angle differences. Returns whether any
    pair passed."""
    ck = k + 1
    scale, count = screw_scale[b, k], screw_count[b, k]
    thr = max(screw_sigma * MAD_TO_STD * scale, screw_gate) if count >= SCREW_MIN_SAMPLES else np.inf
    clip = 5.0 * MAD_TO_STD * scale if count >= SCREW_MIN_SAMPLES else np.inf
    total, n_valid, used = 0.0, 0.0, False
    for j in range(n_pairs):
        pv = prev_valid[0, j] and valid[0] and prev_valid[ck, j] and valid[ck]
        screw = abs(angle[0, j] - angle[ck, j])
        pair_ok[j] = pv and screw <= thr
        used = used or pair_ok[j]
        if pv:
            total += min(screw, clip)
            n_valid += 1.0
    count = min(count + n_valid, SCREW_MAX_SAMPLES)
    screw_scale[b, k] = scale + (total - n_valid * scale) / max(count, 1.0)
    screw_count[b, k] = count
    return used


@_jit
def _update_gaps(
    b,
    k,
    n_pairs,
    quat,
    angle,
    motion,
    pair_ok,
    S2_state,
    V_state,
    rotation_rows_state,
    gap_S2,
    gap_V,
    gap_rotation_rows,
    gap_Z,
    gap_translation_rows,
    lam,
    min_rotation,
    robust,
    symmetric,
    S,
    qs,
    A,
    WV,
    gram,
    w4,
    E4,
    a7,
    newV,
    z,
):
    """Add this frame's pairs of camera k + 1 to each gap's statistics: the rotation rows (robust weights under the
    last frame's combined estimate) by incremental SVD, the translation rows to the gap's 15x15 moment."""
    ck = k + 1
    for i in range(4):
        S[i] = math.sqrt(max(S2_state[b, k, i], 0.0))
    established = _excited(S, rotation_rows_state[b, k], 2, ROTATION_OBSERVABLE_SIGNIFICANCE)
    sign = 1.0 if V_state[b, k, 0, 3] >= 0 else -1.0
    for i in range(4):
        qs[i] = sign * V_state[b, k, i, 3]

    for j in range(n_pairs):
        # A = L(q0) - R(qk), both with w >= 0.
        q0 = quat[0, j]
        q1 = quat[ck, j]
        w0, x0, y0, z0 = q0[0], q0[1], q0[2], q0[3]
        w1, x1, y1, z1 = q1[0], q1[1], q1[2], q1[3]
        A[0, 0], A[0, 1], A[0, 2], A[0, 3] = w0 - w1, -x0 + x1, -y0 + y1, -z0 + z1
        A[1, 0], A[1, 1], A[1, 2], A[1, 3] = x0 - x1, w0 - w1, -z0 - z1, y0 + y1
        A[2, 0], A[2, 1], A[2, 2], A[2, 3] = y0 - y1, z0 + z1, w0 - w1, -x0 - x1
        A[3, 0], A[3, 1], A[3, 2], A[3, 3] = z0 - z1, -y0 - y1, x0 + x1, w0 - w1
        moving = (angle[0, j] + angle[ck, j]) / 2.0 >= min_rotation
        weight = 1.0 if (pair_ok[j] and moving) else 0.0
        if weight > 0.0 and established:
            rr = 0.0
            for i in range(4):
                acc = A[i, 0] * qs[0] + A[i, 1] * qs[1] + A[i, 2] * qs[2] + A[i, 3] * qs[3]
                rr += acc * acc
            dres = 4.0 * math.asin(min(math.sqrt(rr) / 2.0, 1.0))
            if dres > robust:
                weight = robust / max(dres, 1e-12)
        # Incremental SVD of the gap: eigen of lam diag(S2) + (W V)^T (W V), W = sqrt(w) A.
        sw = math.sqrt(weight)
        for i in range(4):
            for m in range(4):
                acc = 0.0
                for l in range(4):
                    acc += A[i, l] * gap_V[b, k, j, l, m]
                WV[i, m] = sw * acc
        for i in range(4):
            for m in range(4):
                acc = 0.0
                for l in range(4):
                    acc += WV[l, i] * WV[l, m]
                gram[i, m] = acc + (lam * gap_S2[b, k, j, i] if i == m else 0.0)
        _eigh4(gram, w4, E4, a7)
        for i in range(4):
            for m in range(4):
                acc = 0.0
                for l in range(4):
                    acc += gap_V[b, k, j, i, l] * E4[l, 3 - m]
                newV[i, m] = acc
        for i in range(4):
            gap_S2[b, k, j, i] = w4[3 - i]
        gap_V[b, k, j] = newV
        gap_rotation_rows[b, k, j] = lam * gap_rotation_rows[b, k, j] + weight
        # Translation moment of the gap.
        w_tr = 1.0 if pair_ok[j] else 0.0
        m0 = motion[0, j]
        mk = motion[ck, j]
        for i in range(3):
            for l in range(3):
                z[0, 3 * i + l] = (1.0 if i == l else 0.0) - m0[i, l]
            z[0, 9 + i] = mk[i, 3]
            z[0, 12 + i] = m0[i, 3]
        n_rows = 1
        if symmetric:  # the reverse pair: R0^T, -R0^T t0, -Rk^T tk
            n_rows = 2
            for i in range(3):
                for l in range(3):
                    z[1, 3 * i + l] = (1.0 if i == l else 0.0) - m0[l, i]
                z[1, 9 + i] = -(mk[0, i] * mk[0, 3] + mk[1, i] * mk[1, 3] + mk[2, i] * mk[2, 3])
                z[1, 12 + i] = -(m0[0, i] * m0[0, 3] + m0[1, i] * m0[1, 3] + m0[2, i] * m0[2, 3])
        Zg = gap_Z[b, k, j]
        if lam != 1.0:
            for i in range(15):
                for l in range(15):
                    Zg[i, l] *= lam
        if pair_ok[j]:  # the moment is symmetric: its upper triangle, mirrored
            for i in range(15):
                for l in range(i, 15):
                    acc = z[0, i] * z[0, l]
                    if n_rows == 2:
                        acc += z[1, i] * z[1, l]
                    Zg[i, l] += acc
                    if l != i:
                        Zg[l, i] = Zg[i, l]
        gap_translation_rows[b, k, j] = lam * gap_translation_rows[b, k, j] + w_tr


@_jit
def _combine_gaps(
    b,
    k,
    n_pairs,
    gap_S2,
    gap_V,
    gap_rotation_rows,
    gap_Z,
    gap_translation_rows,
    S2_state,
    V_state,
    Zc,
    gw,
    Mc,
    WV,
    gram,
    w4,
    E4,
    a7,
    newV,
):
    """The gaps' statistics weighted by their noise (pairing.gap_weights, combine_statistics) into the rotation
    system (``S2_state``, ``V_state``) and the translation moment ``Zc`` (15, 15). Returns the weighted rotation and
    translation row counts."""
    if n_pairs == 1:
        for i in range(4):
            S2_state[b, k, i] = gap_S2[b, k, 0, i]
        V_state[b, k] = gap_V[b, k, 0]
        rows = gap_rotation_rows[b, k, 0]
        Zc[:, :] = gap_Z[b, k, 0]
        trows = gap_translation_rows[b, k, 0]
    else:
        dof_sum, res_sum, top = 0.0, 0.0, 0.0
        for j in range(n_pairs):
            rj = gap_rotation_rows[b, k, j]
            dof_sum += max(2.0 * rj - 3.0, 0.0)
            res_sum += max(gap_S2[b, k, j, 3], 0.0)
            top = max(top, gap_S2[b, k, j, 0] / max(rj, 1.0))
        pooled = res_sum / max(dof_sum, 1.0)
        floor = NOISE_FLOOR * top
        prior, any_measured = 0.0, False
        for j in range(n_pairs):
            dof = max(2.0 * gap_rotation_rows[b, k, j] - 3.0, 0.0)
            shrunk = (max(gap_S2[b, k, j, 3], 0.0) + GAP_PRIOR_DOF * pooled) / (dof + GAP_PRIOR_DOF)
            if dof > 0 and shrunk + floor > 0:
                any_measured = True
                prior = max(prior, shrunk)
        ref = np.inf
        for j in range(n_pairs):
            dof = max(2.0 * gap_rotation_rows[b, k, j] - 3.0, 0.0)
            var = (max(gap_S2[b, k, j, 3], 0.0) + GAP_PRIOR_DOF * prior) / (dof + GAP_PRIOR_DOF) + floor
            gw[j] = var
            if any_measured and var > 0:
                ref = min(ref, var)
        for j in range(n_pairs):
            var = gw[j]
            gw[j] = (ref / var) ** GAP_WEIGHT_POWER if (any_measured and var > 0) else 1.0
        rows, trows = 0.0, 0.0
        for i in range(4):
            for m in range(4):
                Mc[i, m] = 0.0
        for i in range(15):
            for m in range(15):
                Zc[i, m] = 0.0
        for j in range(n_pairs):
            wj = gw[j]
            rows += wj * gap_rotation_rows[b, k, j]
            trows += wj * gap_translation_rows[b, k, j]
            for i in range(4):
                for m in range(4):
                    acc = 0.0
                    for l in range(4):
                        acc += gap_V[b, k, j, i, l] * gap_S2[b, k, j, l] * gap_V[b, k, j, m, l]
                    Mc[i, m] += wj * acc
            Zg = gap_Z[b, k, j]
            for i in range(15):
                for m in range(i, 15):
                    Zc[i, m] += wj * Zg[i, m]
        for i in range(15):
            for m in range(i):
                Zc[i, m] = Zc[m, i]
        # Eigen-decomposition in the basis of the last frame's (nearly diagonal there: fewer sweeps).
        Vb = V_state[b, k]
        for i in range(4):
            for m in range(4):
                WV[i, m] = Mc[i, 0] * Vb[0, m] + Mc[i, 1] * Vb[1, m] + Mc[i, 2] * Vb[2, m] + Mc[i, 3] * Vb[3, m]
        for i in range(4):
            for m in range(4):
                gram[i, m] = Vb[0, i] * WV[0, m] + Vb[1, i] * WV[1, m] + Vb[2, i] * WV[2, m] + Vb[3, i] * WV[3, m]
        _eigh4(gram, w4, E4, a7)
        for i in range(4):
            for m in range(4):
                newV[i, m] = (
                    Vb[i, 0] * E4[0, 3 - m]
                    + Vb[i, 1] * E4[1, 3 - m]
                    + Vb[i, 2] * E4[2, 3 - m]
                    + Vb[i, 3] * E4[3, 3 - m]
                )
        for i in range(4):
            S2_state[b, k, i] = w4[3 - i]
        Vb[:, :] = newV
    return rows, trows


@_jit
def _estimate(
    b,
    k,
    rows,
    trows,
    S2_state,
    V_state,
    Zc,
    refine,
    refine_steps,
    out_rotation,
    out_quaternion,
    out_translation,
    out_scale,
    out_sv,
    out_observable,
    out_planar,
    out_axis,
    out_refined,
    S,
    qs,
    dR,
    P,
    p,
    maps,
    Hn,
    gn,
    xn,
    x,
    axis,
    q_closed,
    x_closed,
    refine_work,
    Mc,
    w4,
    E4,
    w7,
    V7,
    a7,
):
    """Camera k + 1's estimate from the combined statistics (solve.estimate): the rotation (through the translation
    rows on planar motion), the translation and scale, and the joint refinement where asked."""
    for i in range(4):
        S[i] = math.sqrt(max(S2_state[b, k, i], 0.0))
        out_sv[b, k, i] = S[i]
    sign = 1.0 if V_state[b, k, 0, 3] >= 0 else -1.0
    for i in range(4):
        qs[i] = sign * V_state[b, k, i, 3]
    _quat_to_rot(qs, dR)
    planar = _excited(S, rows, 1, ROTATION_OBSERVABLE_SIGNIFICANCE) and not _excited(S, rows, 2, PLANAR_SIGNIFICANCE)
    observable = _excited(S, rows, 2, ROTATION_OBSERVABLE_SIGNIFICANCE)
    c = _quadratic(Zc, P, p)
    axis[:] = 0.0
    if planar:  # planar.planar_rotation: the rotation about the common axis from the translation rows
        Vb = V_state[b, k]
        v3w, v3x, v3y, v3z = Vb[0, 2], -Vb[1, 2], -Vb[2, 2], -Vb[3, 2]  # conj(v3)
        v4w, v4x, v4y, v4z = Vb[0, 3], Vb[1, 3], Vb[2, 3], Vb[3, 3]
        axis[0] = v4w * v3x + v4x * v3w + v4y * v3z - v4z * v3y
        axis[1] = v4w * v3y - v4x * v3z + v4y * v3w + v4z * v3x
        axis[2] = v4w * v3z + v4x * v3y - v4y * v3x + v4z * v3w
        na = max(math.sqrt(axis[0] ** 2 + axis[1] ** 2 + axis[2] ** 2), 1e-300)
        for i in range(3):
            axis[i] /= na
        for i in range(4):
            w4[i] = Vb[i, 3]
        _quat_to_rot(w4, E4)  # R4
        for i in range(3):
            for m in range(3):
                acc0, acc1, acc2 = 0.0, 0.0, 0.0
                for l in range(3):
                    nil = axis[i] * axis[l]
                    acc0 += nil * E4[l, m]
                    acc1 += ((1.0 if i == l else 0.0) - nil) * E4[l, m]
                # skew(n) row i
                if i == 0:
                    acc2 = -axis[2] * E4[1, m] + axis[1] * E4[2, m]
                elif i == 1:
                    acc2 = axis[2] * E4[0, m] - axis[0] * E4[2, m]
                else:
                    acc2 = -axis[1] * E4[0, m] + axis[0] * E4[1, m]
                maps[0, i, m], maps[1, i, m], maps[2, i, m] = acc0, acc1, acc2
        _normal_equations(P, p, maps, 3, Hn, gn)
        _pinv_solve(Hn, gn, 6, xn, w7, V7, a7)
        theta = math.atan2(xn[5], xn[4])
        ct, st = math.cos(theta), math.sin(theta)
        for i in range(3):
            for m in range(3):
                dR[i, m] = maps[0, i, m] + ct * maps[1, i, m] + st * maps[2, i, m]
        _rot_to_quat(dR, qs)
    maps[0] = dR
    _normal_equations(P, p, maps, 1, Hn, gn)
    _spd_solve(Hn, gn, 4, x, w7, V7, a7)
    refined = False
    if refine > 0 and refine_steps > 0:
        active = _excited(S, rows, 1, ROTATION_OBSERVABLE_SIGNIFICANCE) and not planar and trows >= 3
        if refine == 2:
            active = active and not observable
        if active:
            for i in range(4):
                for m in range(4):
                    acc = 0.0
                    for l in range(4):
                        acc += V_state[b, k, i, l] * S2_state[b, k, l] * V_state[b, k, m, l]
                    Mc[i, m] = acc
            q_closed[:] = qs
            x_closed[:] = x
            refined = _joint_refine(Mc, P, p, c, q_closed, x_closed, rows, trows, refine_steps, qs, x, refine_work)
            if refined:
                _quat_to_rot(qs, dR)
    along = axis[0] * x[0] + axis[1] * x[1] + axis[2] * x[2]
    for i in range(3):
        out_translation[b, k, i] = x[i] - axis[i] * along
        out_axis[b, k, i] = axis[i]
    out_scale[b, k] = x[3]
    out_rotation[b, k] = dR
    out_quaternion[b, k] = qs
    out_observable[b, k] = observable
    out_planar[b, k] = planar
    out_refined[b, k] = refined


@_jit
def _rig_step(b, state, config, out, work):
    """One frame of rig ``b``: ``state`` the head's buffers (updated), ``config`` its settings, ``out`` the
    estimate's arrays (written); see :func:`step` for their order. ``work``: :func:`_workspace`."""
    (
        poses,
        history,
        history_valid,
        first,
        first_valid,
        gap_S2,
        gap_V,
        gap_rotation_rows,
        gap_Z,
        gap_translation_rows,
        S2_state,
        V_state,
        rotation_rows_state,
        screw_scale,
        screw_count,
        frames_used,
        frames_rejected,
    ) = state
    (
        gaps,
        has_first,
        frame,
        symmetric,
        lam,
        min_rotation,
        screw_gate,
        screw_sigma,
        robust,
        pose_tolerance,
        refine,
        refine_steps,
    ) = config
    (out_rotation, out_quaternion, out_translation, out_scale, out_sv, out_observable, out_planar, out_axis,
     out_Z, out_translation_rows, out_refined) = out  # fmt: skip
    (pose, valid, motion, prev_valid, prev, quat, angle, A, WV, gram, w4, E4, a7, V7, w7, newV, z, pair_ok, gw, Mc, S, qs, dR, P, p, maps, Hn, gn, xn, x, axis, q_closed, x_closed, refine_work) = work  # fmt: skip
    C = poses.shape[1]
    n_pairs = gaps.shape[0] + (1 if has_first else 0)
    _read_poses(poses, b, pose, valid, pose_tolerance)
    _motion_pairs(
        b,
        pose,
        valid,
        history,
        history_valid,
        first,
        first_valid,
        gaps,
        has_first,
        frame,
        motion,
        prev,
        prev_valid,
        quat,
        angle,
    )
    for k in range(C - 1):
        used = _screw_gate(
            b, k, n_pairs, valid, prev_valid, angle, screw_scale, screw_count, screw_sigma, screw_gate, pair_ok
        )
        _update_gaps(
            b,
            k,
            n_pairs,
            quat,
            angle,
            motion,
            pair_ok,
            S2_state,
            V_state,
            rotation_rows_state,
            gap_S2,
            gap_V,
            gap_rotation_rows,
            gap_Z,
            gap_translation_rows,
            lam,
            min_rotation,
            robust,
            symmetric,
            S,
            qs,
            A,
            WV,
            gram,
            w4,
            E4,
            a7,
            newV,
            z,
        )
        rows, trows = _combine_gaps(
            b,
            k,
            n_pairs,
            gap_S2,
            gap_V,
            gap_rotation_rows,
            gap_Z,
            gap_translation_rows,
            S2_state,
            V_state,
            out_Z[b, k],
            gw,
            Mc,
            WV,
            gram,
            w4,
            E4,
            a7,
            newV,
        )
        rotation_rows_state[b, k] = rows
        out_translation_rows[b, k] = trows
        _estimate(
            b,
            k,
            rows,
            trows,
            S2_state,
            V_state,
            out_Z[b, k],
            refine,
            refine_steps,
            out_rotation,
            out_quaternion,
            out_translation,
            out_scale,
            out_sv,
            out_observable,
            out_planar,
            out_axis,
            out_refined,
            S,
            qs,
            dR,
            P,
            p,
            maps,
            Hn,
            gn,
            xn,
            x,
            axis,
            q_closed,
            x_closed,
            refine_work,
            Mc,
            w4,
            E4,
            w7,
            V7,
            a7,
        )
        frames_used[b, k] += 1 if used else 0
        frames_rejected[b, k] += 1 if (not used and frame > 0) else 0

    slot = frame % history.shape[2]
    for cam in range(C):
        history[b, cam, slot] = pose[cam]
        history_valid[b, cam, slot] = valid[cam]


@_jit
def _serial(state, config, out):
    work = _workspace(state[0].shape[1], config[0].shape[0] + config[1])
    for b in range(state[0].shape[0]):
        _rig_step(b, state, config, out, work)


@njit(cache=True, nogil=True, error_model="numpy", fastmath={"contract", "reassoc"}, parallel=True)
def _parallel(state, config, out, chunks):
    B = state[0].shape[0]
    for chunk in prange(chunks):  # one workspace per chunk of rigs
        work = _workspace(state[0].shape[1], config[0].shape[0] + config[1])
        for b in range(chunk * B // chunks, (chunk + 1) * B // chunks):
            _rig_step(b, state, config, out, work)


def _outputs(head, B: int, K: int) -> dict[str, np.ndarray]:
    """The estimate's arrays: the last frame's once nothing else holds them (no result and no view of one is alive:
    ``torch.from_numpy`` keeps its array referenced), else new ones. A new 15x15 moment per rig and frame costs its
    page faults (~0.5 ms a frame for 4096 rigs)."""
    last = head.__dict__.get("_kernel_outputs")
    if last is not None and all(sys.getrefcount(a) <= 3 for a in last.values()):  # the dict, `a`, the call
        return last
    f64, flag = np.float64, np.bool_
    shapes = {"rotation": ((3, 3), f64), "quaternion": ((4,), f64), "translation": ((3,), f64), "scale": ((), f64),
              "rotation_singular_values": ((4,), f64), "rotation_observable": ((), flag), "planar_motion": ((), flag),
              "planar_axis": ((3,), f64), "translation_moment": ((15, 15), f64), "translation_rows": ((), f64),
              "refined": ((), flag)}  # fmt: skip
    out = {name: np.empty((B, K) + shape, dtype=dtype) for name, (shape, dtype) in shapes.items()}
    head.__dict__["_kernel_outputs"] = out
    return out


def step(head, poses: Tensor) -> dict[str, Tensor]:
    """Run one frame of ``head`` (an :class:`~ocalib.calib.online.OnlineCalibrator` with ``solver="exact"``, float64
    buffers on the CPU) on ``poses`` (B, C, 4, 4), updating its buffers in place. Returns the fields of
    :class:`~ocalib.calib.result.Calibration`; no later frame writes into them while they are alive."""
    st = head._buffers
    B, K = head.batch_size, head.num_cameras - 1
    frame = int(st["frame"])
    out = _outputs(head, B, K)
    state = (poses.detach().to(torch.float64).contiguous().numpy(),) + tuple(st[name].numpy() for name in STATE)
    config = (
        st["gap_tensor"].numpy(),
        0 in head.gaps,
        frame,
        head.symmetric,
        float(head.forgetting),
        head.min_rotation,
        head.screw_gate,
        head.screw_gate_sigma,
        head.robust,
        head.pose_tolerance,
        REFINE_CODES[head.refine],
        3,
    )  # the refinement's steps, as solve.estimate's
    threads = numba.get_num_threads()
    if B >= PARALLEL_MIN_RIGS and threads > 1:
        _parallel(state, config, tuple(out.values()), min(B, 8 * threads))
    else:
        _serial(state, config, tuple(out.values()))
    st["frame"] = st["frame"] + 1
    result = {name: torch.from_numpy(value) for name, value in out.items()}
    result.update(frames_used=st["frames_used"].clone(), frames_rejected=st["frames_rejected"].clone(),
                  rotation_basis=st["V"].clone(), rotation_rows=st["rotation_rows"].clone())  # fmt: skip
    return result
