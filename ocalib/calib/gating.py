"""Robustness of the hand-eye rows: the screw-congruence gate and the down-weighting of large residuals.

Pure functions of the state, shared by the streaming head (:mod:`ocalib.calib.online`) and the
whole-sequence path (:mod:`ocalib.calib.sequence`).

* Screw congruence: the two motions of a rigid rig rotate by the same angle. A pair is rejected when its
  angles differ by more than ``max(gate, sigma * robust std)``, the robust std from a running mean absolute
  difference (each sample clipped at 5 robust std, so outliers barely count; capped at 1000 samples, so it
  follows slow changes). The gate opens after 10 samples.
* VINS-Mono's down-weighting: a rotation row whose residual angle ``d`` under the current estimate exceeds
  ``robust`` weighs ``robust / d``, once rotation is observable.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from ocalib.calib.rotation import rotation_observable, rotation_solution, singular_values

MAD_TO_STD = 1.25  # mean absolute deviation -> standard deviation, for Gaussian noise
SCREW_MIN_SAMPLES = 10
SCREW_MAX_SAMPLES = 1000.0


def screw_threshold(scale: Tensor, count: Tensor, gate: float, sigma: float) -> Tensor:
    """Largest accepted angle difference (radians) (...) from the running ``scale`` and ``count`` (...)."""
    thr = torch.clamp_min(sigma * MAD_TO_STD * scale, gate)
    return torch.where(count >= SCREW_MIN_SAMPLES, thr, math.inf)


def update_screw_scale(scale: Tensor, count: Tensor, screw: Tensor, valid: Tensor) -> tuple[Tensor, Tensor]:
    """Add one frame's angle differences ``screw`` (..., P) of the ``valid`` (..., P) pairs to the running
    mean absolute difference ``scale`` and its sample ``count`` (...)."""
    clip = torch.where(count >= SCREW_MIN_SAMPLES, 5 * MAD_TO_STD * scale, math.inf).unsqueeze(-1)
    x = torch.minimum(screw.detach(), clip) * valid
    n = valid.sum(-1).to(screw.dtype)
    count = (count + n).clamp_max(SCREW_MAX_SAMPLES)
    return scale + (x.sum(-1) - n * scale) / count.clamp_min(1), count


def screw_gate_sequence(
    screw: Tensor, valid: Tensor, scale: Tensor, count: Tensor, gate: float, sigma: float
) -> tuple[Tensor, Tensor, Tensor]:
    """:func:`screw_threshold` and :func:`update_screw_scale` over L frames at once.

    Args:
        screw: (L, ..., P) angle differences, valid: (L, ..., P) pairs, scale, count: (...) the running state
            before the first frame.

    Returns ``ok`` (L, ..., P), the gate's verdicts, and the state after the last frame. The sample count is
    a clamped cumulative sum; the scale is an affine recurrence ``s_t = a_t s_{t-1} + b_t`` once it is known
    which samples are clipped (a clipped sample adds a multiple of ``s_{t-1}``): take the clipping and the
    verdicts from the previous pass's scales until they stop changing (pass k is exact for the first k frames).
    """
    screw = screw.detach()
    n = valid.sum(-1).to(screw.dtype)  # (L, ...)
    counts = (count + n.cumsum(0)).clamp_max(SCREW_MAX_SAMPLES)
    before_count = torch.cat([count.unsqueeze(0), counts[:-1]])
    open_ = (before_count >= SCREW_MIN_SAMPLES).unsqueeze(-1)
    before = scale.expand_as(n)
    verdict = None
    for _ in range(len(screw)):
        clip = torch.where(open_, 5 * MAD_TO_STD * before.unsqueeze(-1), math.inf)
        thr = torch.where(open_, torch.clamp_min(sigma * MAD_TO_STD * before.unsqueeze(-1), gate), math.inf)
        clipped = valid & (screw > clip)
        new = torch.cat([valid & (screw <= thr), clipped], -1)
        if verdict is not None and torch.equal(new, verdict):
            break
        verdict = new
        # A clipped sample adds 5 robust std, i.e. a multiple of s_{t-1}: part of a_t.
        a = 1 - (n - 5 * MAD_TO_STD * clipped.sum(-1)) / counts.clamp_min(1)
        b = (screw * (valid & ~clipped)).sum(-1) / counts.clamp_min(1)
        scales = affine_scan(a, b, scale)
        before = torch.cat([scale.unsqueeze(0), scales[:-1]])
    return verdict[..., : screw.shape[-1]], scales[-1], counts[-1]


def affine_scan(a: Tensor, b: Tensor, s0: Tensor) -> Tensor:
    """``s_t = a_t s_{t-1} + b_t`` for t = 0..L-1 (dim 0) from ``s_{-1} = s0``, in log2(L) doubling steps
    (``a`` broadcasts against ``b``)."""
    a, b, k = a.expand_as(b), b, 1
    while k < len(b):
        a, b = torch.cat([a[:k], a[k:] * a[:-k]]), torch.cat([b[:k], a[k:] * b[:-k] + b[k:]])
        k *= 2
    return a * s0 + b


def robust_weight(S2: Tensor, V: Tensor, rows: Tensor, A: Tensor, robust: float) -> Tensor:
    """Weights (..., P) of rotation blocks ``A`` (..., P, 4, 4) under the estimate of ``(S2, V, rows)`` (..., 4),
    (..., 4, 4), (...): ``robust / d`` where the residual angle ``d`` exceeds ``robust`` and rotation is observable."""
    q = rotation_solution(V).detach()
    r = (A.detach() @ q[..., None, :, None]).squeeze(-1).norm(dim=-1)  # |q0 * dq - dq * q1| = 2 sin(d / 4)
    d = 4 * torch.asin((r / 2).clamp(max=1.0))
    established = rotation_observable(singular_values(S2.detach()), rows.detach()).unsqueeze(-1)
    return torch.where(established & (d > robust), robust / d.clamp_min(1e-12), 1.0)
