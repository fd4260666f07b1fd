"""Robustness of the hand-eye rows: the pose checks, the screw-congruence gate and the weights of the rotation rows.

Pure functions of the state, shared by the streaming head (:mod:`ocalib.calib.drivers.online`) and the
whole-sequence path (:mod:`ocalib.calib.drivers.sequence`); their compiled twins are in
:mod:`ocalib.calib.stages.gating_kernel`.

* Pose checks: a frame's poses must have the rig's shape; a pose with a non-finite entry or a rotation further than
  a tolerance from orthonormal is skipped.
* Screw congruence: the two motions of a rigid rig rotate by the same angle. A pair is rejected when its
  angles differ by more than ``max(gate, sigma * robust std)``, the robust std from a running mean absolute
  difference (each sample clipped at 5 robust std, so outliers barely count; capped at 1000 samples, so it
  follows slow changes). The gate opens after 10 samples.
* Rotation rows: a pair whose motions rotate less than a minimum angle gives none; VINS-Mono's down-weighting: a
  row whose residual angle ``d`` under the current estimate exceeds ``robust`` weighs ``robust / d``, once rotation
  is observable.

Convention: every camera's motions lead with (..., C, P) (P motion pairs), the pairs of camera 0 against camera k
with (..., K, P).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from ocalib.calib.stages.rotation import RotationSystem, rotation_observable, rotation_solution, singular_values
from ocalib.geometry.pose import orthonormality_error

MAD_TO_STD = 1.25  # mean absolute deviation -> standard deviation, for Gaussian noise
SCREW_MIN_SAMPLES = 10
SCREW_MAX_SAMPLES = 1000.0


@dataclass(frozen=True)
class Gates:
    """The head's thresholds of what it trusts (the defaults of :class:`~ocalib.calib.drivers.online.OnlineCalibrator`).

    ``min_rotation_deg``: motions rotating less than this give no rotation rows. ``screw_gate_deg``,
    ``screw_gate_sigma``: a pair is rejected when its two rotation angles differ by more than
    ``max(screw_gate_deg, screw_gate_sigma * robust std of that difference)``. ``robust_deg``: rotation rows whose
    residual exceeds this are down-weighted by ``robust_deg / residual``. ``pose_tolerance``: poses with a non-finite
    entry or a rotation further than this from orthonormal are skipped (and counted in ``frames_rejected``).
    :data:`NO_GATES` turns the minimum rotation, the screw gate and the robust weights off (the paper's head).
    """

    min_rotation_deg: float = 0.05
    screw_gate_deg: float = 1.0
    screw_gate_sigma: float = 4.0
    robust_deg: float = 5.0
    pose_tolerance: float = 1e-3


NO_GATES = Gates(min_rotation_deg=0.0, screw_gate_deg=1e9, robust_deg=1e9)


def rig_poses(poses: Tensor, batch_size: int, num_cameras: int) -> Tensor:
    """A frame's poses (B, C, 4, 4), given as (B, C, 4, 4) or (C, 4, 4) for one rig; any other shape is an error."""
    if poses.dim() == 3:
        poses = poses.unsqueeze(0)
    if poses.shape != (batch_size, num_cameras, 4, 4):
        raise ValueError(f"expected poses of shape ({batch_size}, {num_cameras}, 4, 4), got {tuple(poses.shape)}")
    return poses


def check_poses(poses: Tensor, tolerance: float) -> tuple[Tensor, Tensor]:
    """The poses (..., 4, 4) with the invalid ones (a non-finite entry, or a rotation further than ``tolerance`` from
    orthonormal) replaced by the identity, and which are valid (...). Kernel twin:
    :func:`ocalib.calib.stages.gating_kernel.check_poses`."""
    valid = poses.isfinite().flatten(-2).all(-1)
    eye = torch.eye(4, dtype=poses.dtype, device=poses.device)
    poses = torch.where(valid[..., None, None], poses, eye)  # keep NaN out of the state
    valid = valid & (orthonormality_error(poses[..., :3, :3]) < tolerance)
    return torch.where(valid[..., None, None], poses, eye), valid


def screw_differences(angle: Tensor) -> Tensor:
    """``|angle_0 - angle_k|`` (..., K, P) from every camera's motion angles (..., C, P)."""
    return (angle[..., :1, :] - angle[..., 1:, :]).abs()


def screw_gate(
    angle: Tensor, valid: Tensor, scale: Tensor, count: Tensor, gate: float, sigma: float
) -> tuple[Tensor, Tensor, Tensor]:
    """One frame of the screw-congruence gate.

    Args:
        angle: (..., C, P) every camera's motion angles (radians). valid: (..., K, P) the pairs with both poses valid.
        scale, count: (..., K) the running mean absolute angle difference and its sample count.
        gate, sigma: the threshold ``max(gate, sigma * robust std)``.

    Returns ``ok`` (..., K, P), the pairs that pass, and the updated ``scale, count``. Kernel twin:
    :func:`ocalib.calib.stages.gating_kernel.screw_gate`.
    """
    screw = screw_differences(angle).detach()
    opened = (count >= SCREW_MIN_SAMPLES).unsqueeze(-1)
    thr = torch.where(opened, torch.clamp_min(sigma * MAD_TO_STD * scale, gate).unsqueeze(-1), math.inf)
    clip = torch.where(opened, 5 * MAD_TO_STD * scale.unsqueeze(-1), math.inf)
    x = torch.minimum(screw, clip) * valid
    n = valid.sum(-1).to(screw.dtype)
    count = (count + n).clamp_max(SCREW_MAX_SAMPLES)
    return valid & (screw <= thr), scale + (x.sum(-1) - n * scale) / count.clamp_min(1), count


def screw_gate_sequence(
    angle: Tensor, valid: Tensor, scale: Tensor, count: Tensor, gate: float, sigma: float
) -> tuple[Tensor, Tensor, Tensor]:
    """:func:`screw_gate` over L frames at once.

    Args:
        angle: (L, ..., C, P) motion angles, valid: (L, ..., K, P) pairs, scale, count: (..., K) the running state
            before the first frame.

    Returns ``ok`` (L, ..., K, P), the gate's verdicts, and the state after the last frame. The sample count is
    a clamped cumulative sum; the scale is an affine recurrence ``s_t = a_t s_{t-1} + b_t`` once it is known
    which samples are clipped (a clipped sample adds a multiple of ``s_{t-1}``): take the clipping and the
    verdicts from the previous pass's scales until they stop changing (pass k is exact for the first k frames).
    """
    screw = screw_differences(angle).detach()
    n = valid.sum(-1).to(screw.dtype)  # (L, ..., K)
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


def rotation_weights(
    ok: Tensor, angle: Tensor, A: Tensor, estimate: RotationSystem, min_rotation: float, robust: float
) -> Tensor:
    """Weights (..., K, P) of the rotation blocks ``A`` (..., K, P, 4, 4) of the pairs ``ok`` (..., K, P): none where
    the two motions (every camera's angles (..., C, P)) rotate less than ``min_rotation`` on average; ``robust / d``
    where the residual angle ``d`` under ``estimate`` (..., K) exceeds ``robust`` and rotation is observable, else 1.
    Kernel twin: :func:`ocalib.calib.stages.gating_kernel.rotation_weights`."""
    moving = (angle[..., :1, :] + angle[..., 1:, :]) / 2 >= min_rotation
    q = rotation_solution(estimate.V).detach()
    r = (A.detach() @ q[..., None, :, None]).squeeze(-1).norm(dim=-1)  # |q0 * dq - dq * q1| = 2 sin(d / 4)
    d = 4 * torch.asin((r / 2).clamp(max=1.0))
    established = rotation_observable(singular_values(estimate.S2.detach()), estimate.rotation_rows.detach())
    robust_weight = torch.where(established.unsqueeze(-1) & (d > robust), robust / d.clamp_min(1e-12), 1.0)
    return (ok & moving) * robust_weight
