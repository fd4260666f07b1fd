"""The whole-sequence path: the streaming head's estimate at every frame of a recorded sequence, at once.

:func:`calibrate_sequence` gives what :class:`~ocalib.calib.drivers.online.OnlineCalibrator` returns frame by frame,
with the head's stage functions vectorised over time: all frames' pose checks, motion pairs, hand-eye blocks and
translation moments at once, the statistics accumulated as prefix sums (a scan with the forgetting factor) and
combined, and every frame's estimate (closed form, refinement) solved in one batch. Frames go in chunks (bounded
memory).

The two recursive parts are solved by fixed-point passes over a chunk: the screw gate's running scale (see
:func:`~ocalib.calib.stages.gating.screw_gate_sequence`), and the down-weighting of large rotation residuals
(:func:`~ocalib.calib.stages.gating.rotation_weights`) needs the previous frame's estimate, which a chunk computes
itself: each chunk starts from the estimate before it, then re-weights with its own estimates until the weights stop
changing (one pass when no row is down-weighted, a few when some are). The result equals the stream's to rounding
(tested to 1e-8, with and without outliers).

Convention: as :mod:`ocalib.calib.drivers.online` -- poses (T, [B,] C, 4, 4) camera-to-world, camera 0 the reference.
"""

from __future__ import annotations

from dataclasses import fields

import torch
from torch import Tensor

from ocalib.calib.drivers.online import OnlineCalibrator
from ocalib.calib.drivers.result import Calibration
from ocalib.calib.stages.gating import affine_scan, check_poses, rotation_weights, screw_gate_sequence
from ocalib.calib.stages.handeye import TranslationMoment, rotation_blocks, translation_moment, translation_quadratic
from ocalib.calib.stages.linalg import guarded_eigh
from ocalib.calib.stages.pairing import MotionPairs, combine_statistics, motions_since
from ocalib.calib.stages.refine import refine_estimate
from ocalib.calib.stages.rotation import RotationSystem, rotation_gram
from ocalib.calib.stages.solve import closed_form
from ocalib.calib.stages.translation import fit_scale

PAIRS_PER_CHUNK = 16384  # motion pairs (frames x rigs x cameras x gaps) held at once
WEIGHT_TOLERANCE = 1e-13  # robust weights this close to the previous pass's are final


def calibrate_sequence(poses: Tensor, chunk: int = 1024, progress=None, **options) -> Calibration:
    """Every frame's estimate of the streaming head.

    Args:
        poses: (T, C, 4, 4) or (T, B, C, 4, 4) camera-to-world poses of T frames (of B rigs).
        chunk: frames per chunk (fewer with many rigs: at most ``PAIRS_PER_CHUNK`` motion pairs).
        progress: called with the number of frames done after each chunk, or None.
        options: :class:`~ocalib.calib.drivers.online.OnlineCalibrator` keyword arguments (``solver="exact"``).

    Returns:
        A :class:`~ocalib.calib.drivers.result.Calibration` whose fields lead with (T, K) or (T, B, K).
    """
    single = poses.dim() == 4
    poses = (poses.unsqueeze(1) if single else poses).to(torch.float64)
    T, B, C = poses.shape[:3]
    head = OnlineCalibrator(C, B, device=poses.device, **options)  # the settings, validated
    if head.solver != "exact":
        raise ValueError("calibrate_sequence runs the exact solver; stream the frames through OnlineCalibrator for rls")
    st = dict(head.named_buffers())
    poses, valid = check_poses(poses, head.pose_tolerance)
    index, earlier_valid = _pairs(valid, head.gaps)  # (T, B, P), (T, B, C, P)

    P = index.shape[-1]
    chunk = max(1, min(chunk, PAIRS_PER_CHUNK // (B * C * P)))
    outputs = []
    M = rotation_gram(st["gap_S2"], st["gap_V"])  # each gap's
    for a in range(0, T, chunk):
        frames = torch.arange(a, min(a + chunk, T), device=poses.device)
        earlier = poses[index[frames], torch.arange(B, device=poses.device)[None, :, None]].transpose(2, 3)
        pairs = motions_since(earlier, earlier_valid[frames], poses[frames], valid[frames])
        out, M = _chunk(head, st, pairs, frames, M)
        outputs.append(out)
        if progress is not None:
            progress(len(frames))
    out = {f.name: torch.cat([getattr(o, f.name) for o in outputs]) for f in fields(Calibration)}
    return Calibration(**({k: v.squeeze(1) for k, v in out.items()} if single else out))


def _pairs(valid: Tensor, gaps: tuple[int, ...]) -> tuple[Tensor, Tensor]:
    """Start frame (T, B, P) of every motion pair ending at each frame, and whether the start is valid per camera
    (T, B, C, P) (gap 0: from the first frame with every pose valid, from the frame after)."""
    T, B, C = valid.shape
    t = torch.arange(T, device=valid.device)
    index, ok = [], []
    for g in [g for g in gaps if g > 0] + [g for g in gaps if g == 0]:
        if g > 0:
            start = (t - g).clamp_min(0)[:, None].expand(T, B)
            ok.append((t >= g)[:, None, None] & valid[start, torch.arange(B)])
        else:
            full = valid.all(-1)  # (T, B)
            first = torch.where(full.any(0), full.to(torch.int8).argmax(0), T)  # (B,)
            start = first.clamp_max(T - 1)[None].expand(T, B)
            ok.append((t[:, None] > first)[..., None].expand(T, B, C))
        index.append(start)
    return torch.stack(index, -1), torch.stack(ok, -1)


def _chunk(
    head: OnlineCalibrator, st: dict[str, Tensor], pairs: MotionPairs, frames: Tensor, M: Tensor
) -> tuple[Calibration, Tensor]:
    """The estimates of ``frames`` (L,) from their motion pairs (leading (L, B)); the state ``st`` (and each gap's
    Gram matrix ``M``) move to their end."""
    lam = head.forgetting
    ok, st["screw_scale"], st["screw_count"] = screw_gate_sequence(
        pairs.angle, pairs.valid, st["screw_scale"], st["screw_count"], head.screw_gate, head.screw_gate_sigma
    )
    Z, Z_reverse = translation_moment(pairs.motion, ok, head.symmetric)  # (L, B, K, P, 58) each
    gap_moment = TranslationMoment(
        _scan(Z, st["gap_Z"], lam), _scan(ok.to(M.dtype), st["gap_translation_rows"], lam),
        _scan(Z_reverse, st["gap_Z_reverse"], lam),
    )  # fmt: skip
    # Rotation rows. Their robust weights need the previous frame's estimate: start from the estimate before the
    # chunk, solve, re-weight with the new estimates, until the weights stop changing (one pass when no row is
    # down-weighted; pass k is exact for the chunk's first k frames at least).
    A = rotation_blocks(pairs.quaternion)  # (L, B, K, P, 4, 4)
    before = RotationSystem(*(st[name].unsqueeze(0) for name in RotationSystem._fields))
    weight = rotation_weights(ok, pairs.angle, A, before, head.min_rotation, head.robust)
    for _ in range(len(A)):
        gap_M = _scan(weight[..., None, None] * A.mT @ A, M, lam)  # (L, B, K, P, 4, 4)
        gap_rotation_rows = _scan(weight, st["gap_rotation_rows"], lam)
        # each gap's eigenvalues for its weight, then one eigen-decomposition of the weighted sum
        rotation, moment, _ = combine_statistics(
            gap_M, torch.linalg.eigvalsh(gap_M).flip(-1), gap_rotation_rows, gap_moment
        )
        previous = RotationSystem(*(torch.cat([b, x[:-1]]) for b, x in zip(before, rotation)))
        new = rotation_weights(ok, pairs.angle, A, previous, head.min_rotation, head.robust)
        if bool((new - weight).abs().max() <= WEIGHT_TOLERANCE):
            break
        weight = new
    quadratic = translation_quadratic(moment.Z)
    reverse = translation_quadratic(moment.Z_reverse)  # zero (and weighing nothing) with rows one way
    est = closed_form(rotation, quadratic)
    est = refine_estimate(est, rotation, quadratic, moment.translation_rows, head.refine, reverse=reverse)
    est = fit_scale(est, quadratic, head.scale_fit)

    used = ok.any(-1)
    frames_used = st["frames_used"] + used.cumsum(0)
    frames_rejected = st["frames_rejected"] + (~used & (frames > 0)[:, None, None]).cumsum(0)
    gap_S2, gap_V = (x.flip(-1) for x in guarded_eigh(gap_M[-1]))  # the stream's per-gap state after the chunk
    st.update(gap_S2=gap_S2, gap_V=gap_V, gap_rotation_rows=gap_rotation_rows[-1], S2=rotation.S2[-1],
              V=rotation.V[-1], rotation_rows=rotation.rotation_rows[-1], frames_used=frames_used[-1],
              frames_rejected=frames_rejected[-1])  # fmt: skip
    st.update({"gap_" + name: value[-1] for name, value in gap_moment._asdict().items()})
    return Calibration.from_statistics(est, rotation, moment, frames_used, frames_rejected), gap_M[-1]


def _scan(x: Tensor, carry: Tensor, lam: float) -> Tensor:
    """``s_i = lam s_{i-1} + x_i`` along dim 0 from ``s_{-1} = carry``."""
    if lam == 1.0:
        return carry + x.cumsum(0)
    return affine_scan(x.new_tensor(lam), x, carry)
