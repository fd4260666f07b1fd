"""The distance between two rigid motions, for teaching the pose network the motions that alignment refines.

In training the depth network learns from the pose network's motions refined by Gauss-Newton photometric
alignment (:func:`~ocalib.frontend.align.align_motion`); the refined motion is a better estimate than the
network's own, so the network can also be pulled towards it (``model.distill`` in ``train/``).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor


def motion_distance(T: Tensor, T_ref: Tensor, eps: float = 1e-6) -> tuple[Tensor, Tensor]:
    """Motions (..., 4, 4) and reference motions (..., 4, 4) -> (rotation, translation), each (...).

    ``rotation``: the chordal distance ``|R - R_ref|_F / sqrt(2) = 2 sin(angle / 2)`` in degrees, where ``angle``
    is the rotation angle of ``R_ref^T R``: the angle itself to within 0.01 % below 2 degrees.
    ``translation``: ``|t - t_ref| / |t_ref|``, unitless, so that it does not depend on the network's depth scale.
    Both are smoothed by ``eps`` so that the gradient is finite where the motions agree. A reference that hardly
    translates (``|t_ref|`` near 0, a static pair) makes the translation term large (its denominator is clamped at
    ``eps`` only): train on sequences that move (the synthetic presets always do).

    Convention: both motions in the same frames (e.g. both ``T_target_source``); pass ``T_ref`` detached to use it
    as a target.
    """
    chord = (T[..., :3, :3] - T_ref[..., :3, :3]).square().sum((-2, -1))
    rotation = torch.sqrt(chord + eps**2).sub(eps) * (180.0 / math.pi / math.sqrt(2.0))
    dt = (T[..., :3, 3] - T_ref[..., :3, 3]).square().sum(-1)
    translation = torch.sqrt(dt + eps**2).sub(eps) / T_ref[..., :3, 3].norm(dim=-1).clamp(min=eps)
    return rotation, translation
