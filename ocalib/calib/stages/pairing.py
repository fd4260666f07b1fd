"""Motion pairing: which frame pairs give hand-eye rows, and how much each gap counts.

Rows come from the motions over several frame gaps (``MOTIONS``). Which gaps carry information depends on
the noise: with independent noise on each pose (a SLAM system, the paper's simulation) every gap's motion
is as noisy as a consecutive one, and long gaps carry more signal; with noise on each frame-to-frame motion
accumulated (visual odometry drift), a gap-g motion is g times as noisy and adds nothing the consecutive
motions do not already hold. The head keeps the statistics of each gap apart and weighs each gap by its
residual noise, measured on its own rows: ``w_g = (sigma_min^2 / sigma_g^2)^GAP_WEIGHT_POWER``. Under
independent noise all weights stay near 1; under drift the long gaps fade out. The weights are a function
of the current statistics alone, so a frame's estimate equals the batch solve with those weights.

``sigma_g^2`` is the smallest eigenvalue of gap g's rotation system over its ``2 n_g - 3`` degrees of freedom,
shrunk with ``GAP_PRIOR_DOF`` degrees of freedom toward the noisiest gap's (each first shrunk toward the pooled
value): a gap with a few rows does not decide the weights, and a gap that has just started (under drift, a long
and noisy one) weighs no more than the noisiest gap already measured. Shrinking toward the pooled value instead
let each new gap weigh about 1 for its first frames. The power and the alternatives tried are compared in
``docs/simulation.md``.

Each frame gives every camera's motions over the gaps (:func:`motions_since`) and, once its statistics are updated,
their combination (:func:`combine_statistics`); their compiled twins are in :mod:`ocalib.calib.stages.pairing_kernel`.

Convention: gaps in frames; gap 0 stands for the pair with the first frame. A motion is a camera's pose at the end
of the gap in its own frame at the start (``T_start^-1 T_end``).
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from ocalib.calib.stages.handeye import TranslationMoment
from ocalib.calib.stages.linalg import guarded_eigh
from ocalib.calib.stages.rotation import RotationSystem
from ocalib.geometry.pose import invert_pose
from ocalib.geometry.quaternion import quaternion_angle, rotation_matrix_to_quaternion

MOTIONS = {
    "first": (0,),  # every pose against frame 0: the paper
    "consecutive": (1,),  # frame t-1 to t: visual odometry
    "multi": (1, 2, 4, 8, 16),  # gaps of 1..16 frames, weighted by their noise (see the module docstring)
}
GAP_WEIGHT_POWER = 6.0
GAP_PRIOR_DOF = 20.0
NOISE_FLOOR = 1e-12  # variance floor relative to the largest signal per row: rounding (noise-free data: weights 1)


class MotionPairs(NamedTuple):
    """Every camera's motions over the P gaps of a frame."""

    motion: Tensor  # (..., C, P, 4, 4)
    quaternion: Tensor  # (..., C, P, 4), w >= 0
    angle: Tensor  # (..., C, P) radians
    valid: Tensor  # (..., K, P) bool: the pairs of camera 0 and camera k with all four poses valid


def motions_since(earlier: Tensor, earlier_valid: Tensor, poses: Tensor, valid: Tensor) -> MotionPairs:
    """The motions from the ``earlier`` poses (..., C, P, 4, 4) (valid: (..., C, P)) to ``poses`` (..., C, 4, 4)
    (valid: (..., C)), camera-to-world. Kernel twin: :func:`ocalib.calib.stages.pairing_kernel.motions_since`."""
    motion = invert_pose(earlier) @ poses.unsqueeze(-3)
    q = rotation_matrix_to_quaternion(motion[..., :3, :3])
    both = earlier_valid & valid.unsqueeze(-1)
    return MotionPairs(motion, q, quaternion_angle(q), both[..., :1, :] & both[..., 1:, :])


def gap_weights(S2: Tensor, rows: Tensor) -> Tensor:
    """Weights (..., P) of P gaps from their rotation systems: squared singular values ``S2`` (..., P, 4),
    descending, and weighted row counts ``rows`` (..., P). Gaps without residual (fewer than 2 rows)
    weigh 1. Differentiable: the weights are part of the estimate's function of the poses."""
    dof = (2 * rows - 3).clamp_min(0)
    residual = S2[..., 3].clamp_min(0)
    pooled = residual.sum(-1, keepdim=True) / dof.sum(-1, keepdim=True).clamp_min(1)
    floor = NOISE_FLOOR * (S2[..., 0] / rows.clamp_min(1)).amax(-1, keepdim=True)
    shrunk = (residual + GAP_PRIOR_DOF * pooled) / (dof + GAP_PRIOR_DOF)
    measured = (dof > 0) & (shrunk + floor > 0)
    # Each gap's variance, shrunk toward the noisiest measured gap's: a gap that has just started counts as no
    # better than that until its own rows say otherwise (under drift, a new long gap would otherwise weigh ~1).
    prior = torch.where(measured, shrunk, 0.0).amax(-1, keepdim=True)
    var = (residual + GAP_PRIOR_DOF * prior) / (dof + GAP_PRIOR_DOF) + floor
    known = measured.any(-1, keepdim=True) & (var > 0)
    ref = torch.where(known, var, torch.inf).amin(-1, keepdim=True)
    return torch.where(known, (ref / torch.where(known, var, 1.0)) ** GAP_WEIGHT_POWER, 1.0)


def combine_gaps(weights: Tensor, *statistics: Tensor) -> tuple[Tensor, ...]:
    """Weighted sums over the gap dimension: each statistic (..., P, *) -> (..., *), weights (..., P)."""
    d, w = weights.dim(), weights.unsqueeze(-2)  # (..., 1, P)
    return tuple((w @ x.reshape(*x.shape[:d], -1)).reshape(x.shape[: d - 1] + x.shape[d:]) for x in statistics)


def combine_statistics(
    gap_M: Tensor, gap_S2: Tensor, gap_rotation_rows: Tensor, gap_moment: TranslationMoment
) -> tuple[RotationSystem, TranslationMoment, Tensor]:
    """The rotation system and translation moment of all gaps, weighted by :func:`gap_weights`.

    Args: per gap (..., P, *): the Gram matrix (4, 4) of the rotation rows, its eigenvalues (4), descending, and
    their count; the translation moment.

    Returns the combined rotation system and translation moment (...), and the weights (..., P). Kernel twin:
    :func:`ocalib.calib.stages.pairing_kernel.combine_statistics`.
    """
    w = gap_weights(gap_S2, gap_rotation_rows)
    M, rotation_rows, *moment = combine_gaps(w, gap_M, gap_rotation_rows, *gap_moment)
    evals, evecs = guarded_eigh(M)
    return RotationSystem(evals.flip(-1), evecs.flip(-1), rotation_rows), TranslationMoment(*moment), w
