"""Compiled (numba) per-iteration work of :func:`ocalib.frontend.window.bundle_adjust`: the projection of every
observation and, in one pass over them, its Jacobians, its Cauchy weight and the normal equations' sums.

Every value is rounded as numpy rounds it in the reference written with numpy products (the tests keep it): the
products of small matrices as OpenBLAS's dgemm and dgemv compute them (each entry a chain of fused multiply-adds
over the inner index, starting from zero; a matrix times a vector as ``fma(a2, x2, fma(a0, x0, a1 x1))``), the
contractions of :func:`numpy.einsum` in its order, and each sum of the normal equations in the order of the
observations, every observing frame's term before every anchor's (a sparse summing product's order). No fast-math:
the compiler may neither fuse nor reorder. Where numpy's BLAS rounds otherwise (another library, or a CPU for which
OpenBLAS picks other kernels), the two agree to rounding only.

Convention: as :func:`ocalib.frontend.window.bundle_adjust`: rotations R (F, 3, 3) and centres c (F, 3)
camera-to-world; per observation (M,) its frame, landmark and anchor frame, the bearing (M, 3) of its landmark in
the anchor; inverse depths rho (L,); a frame's 6 unknowns ordered (rotation, centre).
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

# No fastmath: the sums must round exactly as the numpy reference's; numpy's semantics for a division by zero.
jit = njit(cache=True, nogil=True, error_model="numpy")
# The helpers called per observation with many arrays: compiled into their callers, since a call counts a reference
# to each array it is passed (atomics, several ns each).
jit_inline = njit(cache=True, nogil=True, error_model="numpy", inline="always")


@intrinsic
def fma(typingctx, a, b, c):
    """``a * b + c`` (float64) rounded once (LLVM's ``llvm.fma``: the hardware's instruction, or libm's ``fma``)."""
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, signature, args):
        double = ir.DoubleType()
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(double, [double] * 3), "llvm.fma.f64")
        return builder.call(fn, args)

    return sig, codegen


@jit_inline
def _gemm(A, B, out):
    """``out = A @ B`` (2, 3) of A (2, 3) and B (3, 3), as OpenBLAS's dgemm: each entry a chain of fused
    multiply-adds over the inner index from zero, then added to zero (its ``beta = 0`` output)."""
    for i in range(2):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc = fma(A[i, k], B[k, j], acc)
            out[i, j] = acc + 0.0


@jit_inline
def _cross(v, out):
    """``cross_matrix(v)`` (3, 3) of ``v`` (3,) as :func:`ocalib.geometry.se3.cross_matrix` forms it (the upper
    triangle minus its transpose, so the signs of zeros agree too)."""
    out[0, 0], out[0, 1], out[0, 2] = 0.0 - 0.0, -v[2] - 0.0, v[1] - 0.0
    out[1, 0], out[1, 1], out[1, 2] = 0.0 - -v[2], 0.0 - 0.0, -v[0] - 0.0
    out[2, 0], out[2, 1], out[2, 2] = 0.0 - v[1], 0.0 - -v[0], 0.0 - 0.0


@jit
def project(R, cen, rho, frame, landmark, anchor, bearing, K, pixels):
    """The homogeneous points ``Y = R_k^T (R_a b + rho (c_a - c_k))`` (M, 3) in the observing frames and the pixel
    residuals (M, 2) (projection minus ``pixels`` (M, 2)); K (3, 3). A depth within 1e-9 of zero counts as 1e-9."""
    M = frame.shape[0]
    Y = np.empty((M, 3))
    r = np.empty((M, 2))
    u = np.empty(3)
    v = np.empty(3)
    for m in range(M):
        f, a, rl = frame[m], anchor[m], rho[landmark[m]]
        b0, b1, b2 = bearing[m, 0], bearing[m, 1], bearing[m, 2]
        for i in range(3):  # einsum("mij,mj->mi"): two lanes, (j = 0, 2) and (j = 1), then their sum
            lane0 = (0.0 + R[a, i, 0] * b0) + R[a, i, 2] * b2
            lane1 = (0.0 + R[a, i, 1] * b1) + 0.0
            u[i] = (lane0 + lane1) + 0.0
        for i in range(3):
            v[i] = u[i] + rl * (cen[a, i] - cen[f, i])
        for i in range(3):  # einsum("mji,mj->mi"): in j's order, from zero
            Y[m, i] = ((0.0 + R[f, 0, i] * v[0]) + R[f, 1, i] * v[1]) + R[f, 2, i] * v[2]
        z = Y[m, 2] if abs(Y[m, 2]) > 1e-9 else 1e-9
        r[m, 0] = (K[0, 0] * Y[m, 0] / z + K[0, 2]) - pixels[m, 0]
        r[m, 1] = (K[1, 1] * Y[m, 1] / z + K[1, 2]) - pixels[m, 1]
    return Y, r


@jit_inline
def _jacobians(R, cen, f, a, rl, bearing_m, K, Y_m, scratch, J_k, J_a, J_rho):
    """One observation's Jacobians of its pixels (2,): ``J_k`` (2, 6) in its frame's unknowns, ``J_a`` (2, 6) in
    its anchor's, ``J_rho`` (2,) in its landmark's inverse depth; ``rl`` its inverse depth, ``scratch`` (6, 3, 3)."""
    P, PRkT, Q, Ra_cb = scratch[0, :2], scratch[1, :2], scratch[2, :2], scratch[3, :2]
    RkT, C = scratch[4], scratch[5]
    z = Y_m[2]
    P[0, 0], P[0, 1], P[0, 2] = K[0, 0] / z, 0.0, -K[0, 0] * Y_m[0] / (z * z)
    P[1, 0], P[1, 1], P[1, 2] = 0.0, K[1, 1] / z, -K[1, 1] * Y_m[1] / (z * z)
    for i in range(3):
        for j in range(3):
            RkT[i, j] = R[f, j, i]
    _gemm(P, RkT, PRkT)
    d0, d1, d2 = cen[a, 0] - cen[f, 0], cen[a, 1] - cen[f, 1], cen[a, 2] - cen[f, 2]
    for i in range(2):  # dgemv: fma(a2, x2, fma(a0, x0, a1 x1)), added to zero
        J_rho[i] = fma(PRkT[i, 2], d2, fma(PRkT[i, 0], d0, PRkT[i, 1] * d1)) + 0.0
    _cross(Y_m, C)
    _gemm(P, C, Q)
    for i in range(2):
        for j in range(3):
            J_k[i, j] = Q[i, j]
            J_k[i, 3 + j] = -rl * PRkT[i, j]
    _gemm(PRkT, R[a], Q)
    _cross(bearing_m, C)
    _gemm(Q, C, Ra_cb)
    for i in range(2):
        for j in range(3):
            J_a[i, j] = -Ra_cb[i, j]
            J_a[i, 3 + j] = rl * PRkT[i, j]


@jit
def normal_equations(R, cen, rho, frame, landmark, anchor, bearing, K, Y, r, c, F):
    """The Gauss-Newton normal equations of the Cauchy-weighted (scale ``c``, pixels) reprojection errors ``r``
    (M, 2) at the points ``Y`` (M, 3) of :func:`project`, summed per frame (F frames) and landmark (L = len(rho)).

    Returns ``gb`` (F, 6) the gradient per frame, ``Hpl`` (F, L, 6) the frame-landmark blocks, ``Hb`` (F, F, 6, 6)
    the frame-frame blocks, ``Hll`` (L,) and ``gl`` (L,) the inverse depths' diagonal and gradient. Each sum runs
    over the observations in order, the observing frames' terms first, then the anchors' (every product of two
    rows ``A0 B0 + A1 B1``).
    """
    M, L = frame.shape[0], rho.shape[0]
    cc = c * c
    gb = np.zeros((F, 6))
    Hpl = np.zeros((F, L, 6))
    Hb = np.zeros((F, F, 6, 6))
    Hll = np.zeros(L)
    gl = np.zeros(L)
    J_k = np.empty((M, 2, 6))
    J_a = np.empty((M, 2, 6))
    J_rho = np.empty((M, 2))
    w = np.empty(M)
    scratch = np.empty((6, 3, 3))
    for m in range(M):  # the observing frames' terms
        f, a, lm = frame[m], anchor[m], landmark[m]
        _jacobians(R, cen, f, a, rho[lm], bearing[m], K, Y[m], scratch, J_k[m], J_a[m], J_rho[m])
        r0, r1 = r[m, 0], r[m, 1]
        w[m] = 1.0 / (1.0 + (r0 * r0 + r1 * r1) / cc)
        _accumulate(J_k[m], J_k[m], J_a[m], J_rho[m], w[m], r[m], (f, f, a, lm), gb, Hpl, Hb)
        j0, j1 = J_rho[m, 0], J_rho[m, 1]
        Hll[lm] += w[m] * (j0 * j0 + j1 * j1)
        gl[lm] += w[m] * (j0 * r0 + j1 * r1)
    for m in range(M):  # the anchors' terms
        a = anchor[m]
        _accumulate(J_a[m], J_k[m], J_a[m], J_rho[m], w[m], r[m], (a, frame[m], a, landmark[m]), gb, Hpl, Hb)
    return gb, Hpl, Hb, Hll, gl


@jit_inline
def _accumulate(J, J_k, J_a, J_rho, w, r_m, at, gb, Hpl, Hb):
    """Add one observation's terms of one side, its Jacobian ``J`` (2, 6) (``J_k`` or ``J_a``) in frame ``f``, its
    weight ``w`` and residual ``r_m`` (2,), ``at`` = (f, its observing frame fk, its anchor fa, its landmark lm):
    ``J^T w r`` to ``gb[f]``, ``(w J)^T J_rho`` to ``Hpl[f, lm]``, ``(w J)^T J_k`` to ``Hb[f, fk]`` and
    ``(w J)^T J_a`` to ``Hb[f, fa]``."""
    f, fk, fa, lm = at
    wr0, wr1 = w * r_m[0], w * r_m[1]
    for p in range(6):
        gb[f, p] += J[0, p] * wr0 + J[1, p] * wr1
        Hpl[f, lm, p] += (J[0, p] * w) * J_rho[0] + (J[1, p] * w) * J_rho[1]
    for p in range(6):
        Jw0, Jw1 = J[0, p] * w, J[1, p] * w
        for q in range(6):
            Hb[f, fk, p, q] += Jw0 * J_k[0, q] + Jw1 * J_k[1, q]
    for p in range(6):
        Jw0, Jw1 = J[0, p] * w, J[1, p] * w
        for q in range(6):
            Hb[f, fa, p, q] += Jw0 * J_a[0, q] + Jw1 * J_a[1, q]
