"""Compiled twins (numba) of :mod:`ocalib.calib.stages.rotation`: the rotation system's incremental SVD and its tests,
for one rig and camera k (no batch dimension; results written into the arrays passed).

Convention: as :mod:`ocalib.calib.stages.rotation`; squared singular values descending, right singular vectors
as columns.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ocalib.calib.stages.linalg_kernel import eigh4, jit
from ocalib.calib.stages.rotation import ROTATION_OBSERVABLE_MIN_SV


class Workspace(NamedTuple):
    """Scratch arrays of :func:`update_rotation_system`."""

    WV: np.ndarray  # (4, 4)
    gram: np.ndarray  # (4, 4)
    evals: np.ndarray  # (4,)
    evecs: np.ndarray  # (4, 4)
    jacobi: np.ndarray  # (4, 4)


@jit
def workspace():
    return Workspace(np.empty((4, 4)), np.empty((4, 4)), np.empty(4), np.empty((4, 4)), np.empty((4, 4)))


@jit
def update_rotation_system(system, A, weight, forgetting, work):
    """:func:`~ocalib.calib.stages.rotation.update_rotation_system` of each gap, in place: ``system`` a
    :class:`~ocalib.calib.stages.rotation.RotationSystem` of each gap (``S2`` (P, 4), ``V`` (P, 4, 4), ``rotation_rows``
    (P,)), the blocks ``A`` (P, 4, 4) and their ``weight`` (P,). ``work``: :func:`workspace`."""
    S2, V, rows = system
    WV, gram, evals, evecs = work.WV, work.gram, work.evals, work.evecs
    for j in range(A.shape[0]):
        # eigen-decomposition of lam diag(S2) + (W V)^T (W V), W = sqrt(w) A
        sw = math.sqrt(weight[j])
        Aj, Vj = A[j], V[j]
        for i in range(4):
            for m in range(4):
                WV[i, m] = sw * (Aj[i, 0] * Vj[0, m] + Aj[i, 1] * Vj[1, m] + Aj[i, 2] * Vj[2, m] + Aj[i, 3] * Vj[3, m])
        for i in range(4):
            for m in range(4):
                acc = WV[0, i] * WV[0, m] + WV[1, i] * WV[1, m] + WV[2, i] * WV[2, m] + WV[3, i] * WV[3, m]
                gram[i, m] = acc + (forgetting * S2[j, i] if i == m else 0.0)
        eigh4(gram, evals, evecs, work.jacobi)
        rotate_basis(Vj, evecs, WV)
        for i in range(4):
            S2[j, i] = evals[3 - i]
        rows[j] = forgetting * rows[j] + weight[j]


@jit
def rotate_basis(V, evecs, scratch):
    """``V <- V evecs``, the columns of ``evecs`` (4x4, eigenvalues ascending) taken in descending order; ``scratch``
    (4, 4)."""
    for i in range(4):
        for m in range(4):
            scratch[i, m] = (
                V[i, 0] * evecs[0, 3 - m]
                + V[i, 1] * evecs[1, 3 - m]
                + V[i, 2] * evecs[2, 3 - m]
                + V[i, 3] * evecs[3, 3 - m]
            )
    V[:, :] = scratch


@jit
def rotation_gram(S2, V, M):
    """:func:`~ocalib.calib.stages.rotation.rotation_gram`: ``M = V diag(S2) V^T`` (4, 4) written."""
    for i in range(4):
        for m in range(4):
            M[i, m] = (
                V[i, 0] * S2[0] * V[m, 0]
                + V[i, 1] * S2[1] * V[m, 1]
                + V[i, 2] * S2[2] * V[m, 2]
                + V[i, 3] * S2[3] * V[m, 3]
            )


@jit
def singular_values(S2):
    """:func:`~ocalib.calib.stages.rotation.singular_values`, as a 4-tuple."""
    return (
        math.sqrt(max(S2[0], 0.0)),
        math.sqrt(max(S2[1], 0.0)),
        math.sqrt(max(S2[2], 0.0)),
        math.sqrt(max(S2[3], 0.0)),
    )


@jit
def rotation_solution(V):
    """:func:`~ocalib.calib.stages.rotation.rotation_solution`: ``dq`` (w >= 0) from the last column of ``V``, as a
    4-tuple."""
    sign = 1.0 if V[0, 3] >= 0 else -1.0
    return sign * V[0, 3], sign * V[1, 3], sign * V[2, 3], sign * V[3, 3]


@jit
def excited(S, rows, i, significance):
    """:func:`~ocalib.calib.stages.rotation.excited` of singular values ``S`` (4,) and ``rows`` motion pairs."""
    floor = S[3] * S[3]
    excess = (S[i] * S[i] - floor) * math.sqrt(max(2.0 * rows - 3.0, 1.0))
    return S[i] > ROTATION_OBSERVABLE_MIN_SV and excess > significance * floor
