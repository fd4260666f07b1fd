"""Compiled twins (numba) of :mod:`ocalib.calib.stages.handeye`: the hand-eye rows of motion pairs and the translation
moment, for one rig and camera k (no batch dimension; results written into the arrays passed).

Convention: as :mod:`ocalib.calib.stages.handeye`; ``P`` motion pairs, quaternions (w, x, y, z).
"""

from __future__ import annotations

from ocalib.calib.stages.linalg_kernel import jit


@jit
def rotation_blocks(q0, qk, A):
    """:func:`~ocalib.calib.stages.handeye.rotation_blocks`: ``A = L(q0) - R(qk)`` (P, 4, 4) from the motion quaternions
    of camera 0 and camera k (P, 4), both with w >= 0 (as :func:`~ocalib.calib.stages.pairing_kernel.motions_since`
    gives)."""
    for j in range(A.shape[0]):
        w0, x0, y0, z0 = q0[j, 0], q0[j, 1], q0[j, 2], q0[j, 3]
        w1, x1, y1, z1 = qk[j, 0], qk[j, 1], qk[j, 2], qk[j, 3]
        Aj = A[j]
        Aj[0, 0], Aj[0, 1], Aj[0, 2], Aj[0, 3] = w0 - w1, -x0 + x1, -y0 + y1, -z0 + z1
        Aj[1, 0], Aj[1, 1], Aj[1, 2], Aj[1, 3] = x0 - x1, w0 - w1, -z0 - z1, y0 + y1
        Aj[2, 0], Aj[2, 1], Aj[2, 2], Aj[2, 3] = y0 - y1, z0 + z1, w0 - w1, -x0 - x1
        Aj[3, 0], Aj[3, 1], Aj[3, 2], Aj[3, 3] = z0 - z1, -y0 - y1, x0 + x1, w0 - w1


@jit
def pair_features(m0, mk, symmetric, z):
    """:func:`~ocalib.calib.stages.handeye.pair_features` of one motion pair (camera 0's and camera k's motions, 4x4)
    into ``z`` (2, 15); returns the number of rows written (2 if ``symmetric``: the pair and its reverse)."""
    for i in range(3):
        for l in range(3):
            z[0, 3 * i + l] = (1.0 if i == l else 0.0) - m0[i, l]
        z[0, 9 + i] = mk[i, 3]
        z[0, 12 + i] = m0[i, 3]
    if not symmetric:
        return 1
    for i in range(3):  # the reverse pair: R0^T, -R0^T t0, -Rk^T tk
        for l in range(3):
            z[1, 3 * i + l] = (1.0 if i == l else 0.0) - m0[l, i]
        z[1, 9 + i] = -(mk[0, i] * mk[0, 3] + mk[1, i] * mk[1, 3] + mk[2, i] * mk[2, 3])
        z[1, 12 + i] = -(m0[0, i] * m0[0, 3] + m0[1, i] * m0[1, 3] + m0[2, i] * m0[2, 3])
    return 2


@jit
def update_translation_moment(moment, m0, mk, ok, forgetting, symmetric, z):
    """:func:`~ocalib.calib.stages.handeye.update_translation_moment` of one rig and camera k, in place: ``moment`` a
    :class:`~ocalib.calib.stages.handeye.TranslationMoment` of each gap (``Z`` (P, 58), ``translation_rows`` (P,),
    ``Z_reverse`` (P, 58)), the motions of camera 0 and camera k ``m0``, ``mk`` (P, 4, 4), the pairs ``ok`` (P,);
    ``z`` (2, 15) scratch."""
    Z, rows, Z_reverse = moment
    for j in range(Z.shape[0]):
        if forgetting != 1.0:
            for i in range(Z.shape[1]):
                Z[j, i] *= forgetting
                Z_reverse[j, i] *= forgetting
        rows[j] = forgetting * rows[j] + (1.0 if ok[j] else 0.0)
        if not ok[j]:
            continue
        n = pair_features(m0[j], mk[j], symmetric, z)
        add_row_statistics(z[0], Z[j])
        if n == 2:
            add_row_statistics(z[1], Z[j])
            add_row_statistics(z[1], Z_reverse[j])


@jit
def add_row_statistics(z, out):
    """``out += row_statistics(z)`` (:func:`~ocalib.calib.stages.handeye.row_statistics`) for one row's features ``z``
    (15,) into ``out`` (58,)."""
    for i in range(3):
        for j in range(3):
            out[3 * i + j] += z[i] * z[j] + z[3 + i] * z[3 + j] + z[6 + i] * z[6 + j]  # E^T E
            out[36 + 3 * i + j] += z[9 + i] * z[9 + j]  # t1 t1^T
            out[48 + 3 * i + j] += z[12 + i] * z[9 + j]  # t0[r] t1[j]
            for r in range(3):
                out[9 + 9 * i + 3 * r + j] += z[3 * r + i] * z[9 + j]  # E[r, i] t1[j]
        out[45 + i] += z[i] * z[12] + z[3 + i] * z[13] + z[6 + i] * z[14]  # E^T t0
    out[57] += z[12] * z[12] + z[13] * z[13] + z[14] * z[14]


@jit
def translation_quadratic(Z, P, p):
    """:func:`~ocalib.calib.stages.handeye.translation_quadratic` of ``Z`` (58,): ``P`` (12, 12) and ``p`` (12,)
    written, ``c`` returned."""
    for i in range(12):
        for j in range(12):
            P[i, j] = 0.0
    for i in range(3):
        for j in range(3):
            P[i, j] = Z[3 * i + j]
        for j in range(9):
            P[i, 3 + j] = Z[9 + 9 * i + j]
            P[3 + j, i] = Z[9 + 9 * i + j]
    for a in range(3):
        for b in range(3):
            for d in range(3):
                P[3 + 3 * a + b, 3 + 3 * a + d] = Z[36 + 3 * b + d]
    for i in range(12):
        p[i] = Z[45 + i]
    return Z[57]


@jit
def apply_quadratic(P, y, out):
    """``out = P y`` for the quadratic's ``P`` (12, 12), whose lower-right block is ``I (x) Z_t1t1``."""
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


@jit
def normal_equations(quadratic, maps, m, H, g):
    """:func:`~ocalib.calib.stages.handeye.normal_equations` of ``quadratic`` ``(P, p, c)`` for the first ``m`` maps of
    ``maps`` (3, 3, 3): ``H`` ((3 + m) x (3 + m) block) and ``g`` written."""
    P, p, _ = quadratic
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
