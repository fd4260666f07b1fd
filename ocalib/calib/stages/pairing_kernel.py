"""Compiled twins (numba) of :mod:`ocalib.calib.stages.pairing`: a frame's motion pairs and the combination of the gaps'
statistics, for one rig (no batch dimension; results written into the arrays passed).

Convention: as :mod:`ocalib.calib.stages.pairing`; every camera's motions (C, P), the pairs of camera 0 against camera k
(K, P) or, for one camera k, (P,).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ocalib.calib.stages.linalg_kernel import eigh4, jit, rotation_matrix_to_quaternion
from ocalib.calib.stages.pairing import GAP_PRIOR_DOF, GAP_WEIGHT_POWER, NOISE_FLOOR
from ocalib.calib.stages.rotation_kernel import rotate_basis, rotation_gram


@jit
def motions_since(earlier, earlier_valid, poses, valid, pairs):
    """:func:`~ocalib.calib.stages.pairing.motions_since` of a rig: the ``earlier`` poses (C, P, 4, 4) (valid: (C, P)),
    the poses (C, 4, 4) (valid: (C,)); ``pairs`` a :class:`~ocalib.calib.stages.pairing.MotionPairs` of arrays,
    written."""
    C, n_pairs = earlier_valid.shape
    for cam in range(C):
        for j in range(n_pairs):
            prev, m = earlier[cam, j], pairs.motion[cam, j]
            for i in range(3):  # inv(prev) @ pose
                for k in range(4):
                    acc = 0.0
                    for l in range(3):
                        acc += prev[l, i] * (poses[cam, l, k] - (prev[l, 3] if k == 3 else 0.0))
                    m[i, k] = acc
            m[3, 0], m[3, 1], m[3, 2], m[3, 3] = 0.0, 0.0, 0.0, 1.0
            q = pairs.quaternion[cam, j]
            rotation_matrix_to_quaternion(m, q)
            pairs.angle[cam, j] = 2.0 * math.atan2(math.sqrt(q[1] * q[1] + q[2] * q[2] + q[3] * q[3]), abs(q[0]))
    for k in range(C - 1):
        for j in range(n_pairs):
            pairs.valid[k, j] = earlier_valid[0, j] and valid[0] and earlier_valid[k + 1, j] and valid[k + 1]


@jit
def gap_weights(S2, rows, w):
    """:func:`~ocalib.calib.stages.pairing.gap_weights` of P gaps (``S2`` (P, 4), ``rows`` (P,)): ``w`` (P,) written."""
    n_gaps = rows.shape[0]
    dof_sum, res_sum, top = 0.0, 0.0, 0.0
    for j in range(n_gaps):
        dof_sum += max(2.0 * rows[j] - 3.0, 0.0)
        res_sum += max(S2[j, 3], 0.0)
        top = max(top, S2[j, 0] / max(rows[j], 1.0))
    pooled = res_sum / max(dof_sum, 1.0)
    floor = NOISE_FLOOR * top
    prior, measured = 0.0, False
    for j in range(n_gaps):
        dof = max(2.0 * rows[j] - 3.0, 0.0)
        shrunk = (max(S2[j, 3], 0.0) + GAP_PRIOR_DOF * pooled) / (dof + GAP_PRIOR_DOF)
        if dof > 0 and shrunk + floor > 0:
            measured = True
            prior = max(prior, shrunk)
    ref = np.inf
    for j in range(n_gaps):  # each gap's variance, shrunk toward the noisiest measured gap's
        dof = max(2.0 * rows[j] - 3.0, 0.0)
        w[j] = (max(S2[j, 3], 0.0) + GAP_PRIOR_DOF * prior) / (dof + GAP_PRIOR_DOF) + floor
        if measured and w[j] > 0:
            ref = min(ref, w[j])
    for j in range(n_gaps):
        w[j] = (ref / w[j]) ** GAP_WEIGHT_POWER if (measured and w[j] > 0) else 1.0


class Workspace(NamedTuple):
    """Scratch arrays of :func:`combine_statistics`."""

    weights: np.ndarray  # (P,)
    M: np.ndarray  # (4, 4)
    gram: np.ndarray  # (4, 4)
    evals: np.ndarray  # (4,)
    evecs: np.ndarray  # (4, 4)
    jacobi: np.ndarray  # (4, 4)


@jit
def workspace(n_pairs):
    return Workspace(
        np.empty(n_pairs), np.empty((4, 4)), np.empty((4, 4)), np.empty(4), np.empty((4, 4)), np.empty((4, 4))
    )


@jit
def combine_statistics(gaps, gap_moment, S2, V, Z, Z_reverse, work):
    """:func:`~ocalib.calib.stages.pairing.combine_statistics` for one rig and camera k: ``gaps`` a
    :class:`~ocalib.calib.stages.rotation.RotationSystem` and ``gap_moment`` a
    :class:`~ocalib.calib.stages.handeye.TranslationMoment` of each gap ((P, *)); writes the combined rotation system's
    ``S2`` (4,) and ``V`` (4, 4) and the moment ``Z`` (58,) and its reverse rows' share ``Z_reverse``, returns their row
    counts. Unlike the PyTorch stage it takes each gap's ``(S2, V)`` for its Gram matrix; one gap is its own combination
    (PyTorch decomposes its Gram matrix again: the same to rounding). ``V`` comes in as the last frame's, the basis the
    combined Gram matrix is decomposed in (nearly diagonal there: fewer Jacobi sweeps). ``work``: :func:`workspace`."""
    gap_S2, gap_V, gap_rows = gaps
    gap_Z, gap_translation_rows, gap_Z_reverse = gap_moment
    if gap_rows.shape[0] == 1:
        S2[:], V[:, :], Z[:], Z_reverse[:] = gap_S2[0], gap_V[0], gap_Z[0], gap_Z_reverse[0]
        return gap_rows[0], gap_translation_rows[0]
    w, M, gram = work.weights, work.M, work.gram
    gap_weights(gap_S2, gap_rows, w)
    rows, translation_rows = 0.0, 0.0
    M[:, :] = 0.0
    Z[:] = 0.0
    Z_reverse[:] = 0.0
    for j in range(gap_rows.shape[0]):
        rows += w[j] * gap_rows[j]
        translation_rows += w[j] * gap_translation_rows[j]
        rotation_gram(gap_S2[j], gap_V[j], gram)
        for i in range(4):
            for m in range(4):
                M[i, m] += w[j] * gram[i, m]
        for i in range(Z.shape[0]):
            Z[i] += w[j] * gap_Z[j, i]
            Z_reverse[i] += w[j] * gap_Z_reverse[j, i]
    for i in range(4):  # M in the basis V: V^T M V
        for m in range(4):
            gram[i, m] = M[i, 0] * V[0, m] + M[i, 1] * V[1, m] + M[i, 2] * V[2, m] + M[i, 3] * V[3, m]
    for i in range(4):
        for m in range(4):
            M[i, m] = V[0, i] * gram[0, m] + V[1, i] * gram[1, m] + V[2, i] * gram[2, m] + V[3, i] * gram[3, m]
    eigh4(M, work.evals, work.evecs, work.jacobi)
    rotate_basis(V, work.evecs, gram)
    for i in range(4):
        S2[i] = work.evals[3 - i]
    return rows, translation_rows
