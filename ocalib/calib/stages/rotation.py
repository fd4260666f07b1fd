"""Rotation of the rig by incremental SVD of the stacked hand-eye blocks (the paper's Algorithm 1).

The stacked system ``[A_1; A_2; ...] dq = 0`` is never stored: only its right singular vectors ``V``
(..., 4, 4) and singular values ``S`` (..., 4), descending. New rows ``W`` (..., r, 4) update them by
the SVD of the small matrix ``[sqrt(lam) diag(S); W V]``; ``dq`` is the last column of ``V``. The
state carries ``S2 = S^2``: the square root at a zero singular value (the start, noise-free data)
would cut the gradient, and ``S2`` is what the update needs.

The small SVD is taken through its 4x4 Gram matrix ``lam diag(S^2) + (W V)^T (W V)`` with
:func:`~ocalib.calib.stages.linalg.guarded_eigh`: the same right singular vectors and singular values,
3x faster on large batches of rigs, and with gradients that stay finite on planar motion. Singular
values near zero are then accurate to about ``sqrt(machine eps) * S[0]`` in absolute terms.

The compiled twins are in :mod:`ocalib.calib.stages.rotation_kernel`.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from ocalib.calib.stages.linalg import guarded_eigh
from ocalib.geometry.quaternion import canonical_quaternion, left_product_matrix, quaternion_conjugate

ROTATION_OBSERVABLE_MIN_SV = 0.1  # S[2] must exceed this (a ~6 degree motion, or many smaller ones) ...
# ... and stand out of the noise floor: (S[2]^2 / S[3]^2 - 1) sqrt(2 n - 3) > this. Over n rows, S[3]^2 is the
# residual (noise) and S[2]^2 noise plus signal; their ratio falls as 1 / sqrt(dof) for noise alone. Measured
# (docs/simulation.md): noise-only directions (planar car, sigma 0.01-0.05) reach 12 at most, median 4.
ROTATION_OBSERVABLE_SIGNIFICANCE = 20.0
PLANAR_SIGNIFICANCE = 12.0  # planar motion: the third direction is below this (consistent with noise alone)


class RotationSystem(NamedTuple):
    """The weighted rotation rows ``[A_1; A_2; ...]``, kept as their SVD (the field names are the head's buffers')."""

    S2: Tensor  # (..., 4) squared singular values, descending
    V: Tensor  # (..., 4, 4) right singular vectors (columns)
    rotation_rows: Tensor  # (...) weighted number of motion pairs


def update_rotation_system(system: RotationSystem, A: Tensor, weight: Tensor, forgetting: float) -> RotationSystem:
    """Add blocks ``A`` (..., 4, 4) with row weights ``weight`` (...) to ``system`` (...): one step of incremental
    SVD, old rows weighing ``forgetting``. Kernel twin:
    :func:`ocalib.calib.stages.rotation_kernel.update_rotation_system`."""
    S2, V = incremental_svd_update(system.S2, system.V, weight.sqrt()[..., None, None] * A, forgetting)
    return RotationSystem(S2, V, forgetting * system.rotation_rows + weight)


def rotation_gram(S2: Tensor, V: Tensor) -> Tensor:
    """The Gram matrix ``V diag(S2) V^T`` (..., 4, 4) of the rotation rows: what ``(S2, V)`` stand for, whatever basis
    a repeated eigenvalue got."""
    return (V * S2.unsqueeze(-2)) @ V.mT


def incremental_svd_update(S2: Tensor, V: Tensor, W: Tensor, forgetting: float = 1.0) -> tuple[Tensor, Tensor]:
    """One step of incremental SVD.

    Args:
        S2: (..., 4) squared singular values so far, descending. V: (..., 4, 4) right singular vectors
            (columns). W: (..., r, 4) new rows (already weighted). forgetting: ``lam`` in (0, 1], old
            rows weigh ``lam``.

    Returns:
        The updated ``(S2, V)`` of the stacked matrix ``[sqrt(lam) * old; W]``.
    """
    WV = W @ V
    gram = torch.diag_embed(forgetting * S2) + WV.mT @ WV
    evals, evecs = guarded_eigh(gram)
    return evals.flip(-1), V @ evecs.flip(-1)


def singular_values(S2: Tensor) -> Tensor:
    """Singular values (..., 4) from their squares (rounding can make a zero one slightly negative)."""
    return S2.clamp_min(0).sqrt()


def rotation_solution(V: Tensor) -> Tensor:
    """Quaternion ``dq`` (..., 4), w >= 0: the right singular vector of the smallest singular value."""
    return canonical_quaternion(V[..., :, 3])


def batch_rotation(A: Tensor, weights: Tensor | None = None) -> tuple[Tensor, Tensor, Tensor]:
    """Batch reference (Esquivel et al. 2007): SVD of all stacked blocks at once.

    Args:
        A: (..., N, 4, 4) blocks. weights: (..., N) row weights (each block is scaled by sqrt(w)).

    Returns:
        dq (..., 4) with w >= 0, S (..., 4) descending, V (..., 4, 4).
    """
    if weights is not None:
        A = A * weights.sqrt()[..., None, None]
    stacked = A.flatten(-3, -2)
    _, S, Vh = torch.linalg.svd(stacked, full_matrices=False)
    V = Vh.mT
    return rotation_solution(V), S, V


def rotation_observable(S: Tensor, rows: Tensor) -> Tensor:
    """Rotation is observable when the 3-D orthogonal complement of ``dq`` is excited: ``S[2] > 0.1`` and
    ``S[2]`` significantly above the noise floor ``S[3]`` given the ``rows`` motion pairs (see
    ``ROTATION_OBSERVABLE_SIGNIFICANCE``). Shapes (..., 4), (...) -> (...) bool."""
    return excited(S, rows, 2)


def planar_motion(S: Tensor, rows: Tensor) -> Tensor:
    """All rotation axes (nearly) parallel: two directions excited (as :func:`rotation_observable` asks
    of three) and the third not out of the noise (``PLANAR_SIGNIFICANCE``; between the two thresholds the
    motion is neither: the joint refinement takes the third direction from the translation rows).
    Shapes (..., 4), (...) -> (...) bool.

    Measured (docs/simulation.md): a test on the third singular value alone (``S[2]`` at the noise floor)
    misses exactly planar noise-free motion and near-planar motion; the null-space solution is then
    wrong by degrees, the translation route is not.
    """
    return excited(S, rows, 1) & ~excited(S, rows, 2, PLANAR_SIGNIFICANCE)


def excited(S: Tensor, rows: Tensor, i: int, significance: float = ROTATION_OBSERVABLE_SIGNIFICANCE) -> Tensor:
    """Whether direction ``i`` (0-2) of the rotation system is excited: its singular value above
    ``ROTATION_OBSERVABLE_MIN_SV`` and out of the noise floor ``S[3]`` given ``rows`` motion pairs.
    Shapes (..., 4), (...) -> (...) bool."""
    floor = S[..., 3].square()
    excess = (S[..., i].square() - floor) * (2 * rows - 3).clamp_min(1).sqrt()
    return (S[..., i] > ROTATION_OBSERVABLE_MIN_SV) & (excess > significance * floor)


def rotation_std(S: Tensor, V: Tensor, rows: Tensor) -> Tensor:
    """1-sigma rotation error (..., 3) in radians, about camera k's axes, from first-order perturbation.

    ``cov(dq) = sigma^2 sum_{i<4} v_i v_i^T / S_i^2`` with ``sigma^2 = S_3^2 / (2 n - 3)``: each block
    has rank 2, so ``rows`` (...) blocks give ``2 n`` equations for 3 degrees of freedom (infinite with
    ``2 n <= 3``: the residual says nothing then). The rotation vector error is ``2 vec(conj(dq) * d dq)``.
    """
    dof = 2 * rows - 3
    sigma2 = torch.where(dof > 0, S[..., 3] ** 2 / dof.clamp_min(1), torch.inf)  # no residual to tell: unknown
    Vt = V[..., :, :3] / S[..., None, :3].clamp_min(1e-300)
    q = rotation_solution(V)
    conj = quaternion_conjugate(q)
    J = 2 * left_product_matrix(conj)[..., 1:, :]  # (..., 3, 4)
    JV = J @ Vt
    return (sigma2[..., None] * (JV * JV).sum(-1)).sqrt()
