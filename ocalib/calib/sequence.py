"""The whole-sequence path: the streaming head's estimate at every frame of a recorded sequence, at once.

:func:`calibrate_sequence` gives what :class:`~ocalib.calib.online.OnlineCalibrator` returns frame by frame,
but computes all frames' motions, hand-eye blocks and translation features in tensors, accumulates the
statistics as prefix sums (a scan with the forgetting factor), and solves every frame's estimate in one
batch (:func:`~ocalib.calib.solve.estimate`). Frames go in chunks (bounded memory).

The two recursive parts are solved by fixed-point passes over a chunk: the screw gate's running scale (see
:func:`~ocalib.calib.gating.screw_gate_sequence`), and the down-weighting of large rotation residuals (:func:`~ocalib.calib.gating.robust_weight`) needs the
previous frame's estimate, which a chunk computes itself: each chunk starts from the estimate before it,
then re-weights with its own estimates until the weights stop changing (one pass when no row is
down-weighted, a few when some are). The result equals the stream's to rounding (tested to 1e-8, with and
without outliers).

Convention: as :mod:`ocalib.calib.online` -- poses (T, [B,] C, 4, 4) camera-to-world, camera 0 the reference.
"""

from __future__ import annotations

import torch
from torch import Tensor

from ocalib.calib.gating import affine_scan, robust_weight, screw_gate_sequence
from ocalib.calib.handeye import pair_features, rotation_block
from ocalib.calib.linalg import guarded_eigh
from ocalib.calib.online import OnlineCalibrator
from ocalib.calib.pairing import combine_statistics
from ocalib.calib.result import Calibration
from ocalib.calib.solve import estimate
from ocalib.geometry.pose import invert_pose, orthonormality_error
from ocalib.geometry.quaternion import quaternion_angle, rotation_matrix_to_quaternion

PAIRS_PER_CHUNK = 16384  # motion pairs (frames x rigs x cameras x gaps) held at once
WEIGHT_TOLERANCE = 1e-13  # robust weights this close to the previous pass's are final


def calibrate_sequence(poses: Tensor, chunk: int = 1024, progress=None, **options) -> Calibration:
    """Every frame's estimate of the streaming head.

    Args:
        poses: (T, C, 4, 4) or (T, B, C, 4, 4) camera-to-world poses of T frames (of B rigs).
        chunk: frames per chunk (fewer with many rigs: at most ``PAIRS_PER_CHUNK`` motion pairs).
        progress: called with the number of frames done after each chunk, or None.
        options: :class:`~ocalib.calib.online.OnlineCalibrator` keyword arguments (``solver="exact"``).

    Returns:
        A :class:`~ocalib.calib.result.Calibration` whose fields lead with (T, K) or (T, B, K).
    """
    single = poses.dim() == 4
    poses = (poses.unsqueeze(1) if single else poses).to(torch.float64)
    T, B, C = poses.shape[:3]
    head = OnlineCalibrator(C, B, device=poses.device, **options)  # the settings, validated
    if head.solver != "exact":
        raise ValueError("calibrate_sequence runs the exact solver; stream the frames through OnlineCalibrator for rls")
    st = dict(head.named_buffers())
    valid = poses.isfinite().flatten(-2).all(-1)
    eye = torch.eye(4, dtype=poses.dtype, device=poses.device)
    poses = torch.where(valid[..., None, None], poses, eye)
    valid = valid & (orthonormality_error(poses[..., :3, :3]) < head.pose_tolerance)
    poses = torch.where(valid[..., None, None], poses, eye)
    index, pair_valid = _pairs(valid, head.gaps)  # (T, B, P), (T, B, C, P)

    P = index.shape[-1]
    chunk = max(1, min(chunk, PAIRS_PER_CHUNK // (B * C * P)))
    lam, outputs = head.forgetting, []
    M = (st["gap_V"] * st["gap_S2"].unsqueeze(-2)) @ st["gap_V"].mT  # each gap's Gram matrix
    for a in range(0, T, chunk):
        frames = torch.arange(a, min(a + chunk, T), device=poses.device)
        out, M = _chunk(head, st, poses, valid, index, pair_valid, frames, M, lam)
        outputs.append(out)
        if progress is not None:
            progress(len(frames))
    fields = {k: torch.cat([o[k] for o in outputs]) for k in outputs[0]}
    if single:
        fields = {k: v.squeeze(1) for k, v in fields.items()}
    return Calibration(**fields)


def _pairs(valid: Tensor, gaps: tuple[int, ...]) -> tuple[Tensor, Tensor]:
    """Start frame (T, B, P) of every motion pair ending at each frame, and its validity per camera
    (T, B, C, P): both poses valid (gap 0: from the first frame with every pose valid, from the frame after)."""
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
    return torch.stack(index, -1), torch.stack(ok, -1) & valid.unsqueeze(-1)


def _chunk(head, st, poses, valid, index, pair_valid, frames, M, lam) -> tuple[dict[str, Tensor], Tensor]:
    """The estimates of ``frames`` (L,); the state ``st`` (and each gap's Gram matrix ``M``) move to their end."""
    L, B = len(frames), valid.shape[1]
    rigs = torch.arange(B, device=poses.device)
    start = poses[index[frames], rigs[None, :, None]]  # (L, B, P, C, 4, 4)
    motion = invert_pose(start.transpose(2, 3)) @ poses[frames].unsqueeze(3)  # (L, B, C, P, 4, 4)
    pv = pair_valid[frames]
    pv = pv[:, :, :1] & pv[:, :, 1:]  # (L, B, K, P)
    q = rotation_matrix_to_quaternion(motion[..., :3, :3])
    angle = quaternion_angle(q)
    screw = (angle[:, :, :1] - angle[:, :, 1:]).abs()

    ok, st["screw_scale"], st["screw_count"] = screw_gate_sequence(
        screw, pv, st["screw_scale"], st["screw_count"], head.screw_gate, head.screw_gate_sigma
    )

    # Rotation rows. Their robust weights need the previous frame's estimate: start from the estimate before
    # the chunk, solve, re-weight with the new estimates, until the weights stop changing (one pass when no
    # row is down-weighted; pass k is exact for the chunk's first k frames at least).
    A = rotation_block(q[:, :, :1].expand_as(q[:, :, 1:]), q[:, :, 1:])  # (L, B, K, P, 4, 4)
    rows = (ok & ((angle[:, :, :1] + angle[:, :, 1:]) / 2 >= head.min_rotation)).to(poses.dtype)
    w_tr = ok.to(poses.dtype)
    z = pair_features(motion[:, :, :1].expand_as(motion[:, :, 1:]), motion[:, :, 1:], head.symmetric)
    gap_Z = _scan((z * w_tr[..., None, None]).mT @ z, st["gap_Z"], lam)  # (L, B, K, P, 15, 15)
    gap_translation_rows = _scan(w_tr, st["gap_translation_rows"], lam)
    before = st["S2"].unsqueeze(0), st["V"].unsqueeze(0), st["rotation_rows"].unsqueeze(0)
    weight = robust_weight(*before, A, head.robust)
    for _ in range(L):
        w_rot = rows * weight
        gap_M = _scan(w_rot[..., None, None] * A.mT @ A, M, lam)  # (L, B, K, P, 4, 4)
        gap_rotation_rows = _scan(w_rot, st["gap_rotation_rows"], lam)
        if gap_M.shape[-3] == 1:  # one gap: its statistics as they are
            evals, evecs = guarded_eigh(gap_M[..., 0, :, :])
            S2, V, rotation_rows = evals.flip(-1), evecs.flip(-1), gap_rotation_rows[..., 0]
            Z, translation_rows = gap_Z[..., 0, :, :], gap_translation_rows[..., 0]
        else:  # each gap's eigenvalues for its weight, then one eigen-decomposition of the weighted sum
            S2, V, rotation_rows, Z, translation_rows, _ = combine_statistics(
                gap_M, torch.linalg.eigvalsh(gap_M).flip(-1), gap_rotation_rows, gap_Z, gap_translation_rows
            )
        previous = [torch.cat([b, x[:-1]]) for b, x in zip(before, (S2, V, rotation_rows))]
        new = robust_weight(*previous, A, head.robust)
        if bool((new - weight).abs().max() <= WEIGHT_TOLERANCE):
            break
        weight = new
    est = estimate(S2, V, Z, rotation_rows, translation_rows, head.refine)

    used = ok.any(-1)
    frames_used = st["frames_used"] + used.cumsum(0)
    frames_rejected = st["frames_rejected"] + (~used & (frames > 0)[:, None, None]).cumsum(0)
    gap_S2, gap_V = (x.flip(-1) for x in guarded_eigh(gap_M[-1]))  # the stream's per-gap state after the chunk
    st.update(gap_S2=gap_S2, gap_V=gap_V, gap_rotation_rows=gap_rotation_rows[-1], gap_Z=gap_Z[-1],
              gap_translation_rows=gap_translation_rows[-1], S2=S2[-1], V=V[-1], rotation_rows=rotation_rows[-1],
              frames_used=frames_used[-1], frames_rejected=frames_rejected[-1])  # fmt: skip
    return {
        "rotation": est["rotation"],
        "quaternion": est["quaternion"],
        "translation": est["translation"],
        "scale": est["scale"],
        "rotation_singular_values": est["singular_values"],
        "rotation_observable": est["observable"],
        "planar_motion": est["planar"],
        "planar_axis": est["axis"],
        "frames_used": frames_used,
        "frames_rejected": frames_rejected,
        "rotation_basis": V,
        "rotation_rows": rotation_rows,
        "translation_moment": Z,
        "translation_rows": translation_rows,
        "refined": est["refined"],
    }, gap_M[-1]


def _scan(x: Tensor, carry: Tensor, lam: float) -> Tensor:
    """``s_i = lam s_{i-1} + x_i`` along dim 0 from ``s_{-1} = carry``."""
    if lam == 1.0:
        return carry + x.cumsum(0)
    return affine_scan(x.new_tensor(lam), x, carry)
