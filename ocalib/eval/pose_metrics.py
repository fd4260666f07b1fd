"""Ego-motion error metrics: SfMLearner's 5-frame snippet ATE, ATE and RPE after Sim(3) alignment,
frame-to-frame rotation and translation-direction errors, the per-frame scale ratio, and the rotation gain
per camera axis.

Convention: poses are camera-to-world (N, 4, 4) float64 numpy arrays, predicted and ground truth for the same
N frames, each in its own world frame and units (predictions are up to scale). The frame-to-frame motion is
``T_{t-1,t} = P_{t-1}^-1 P_t``, the pose of frame t in frame t-1's camera frame.
"""

from __future__ import annotations

import numpy as np

from ocalib.errors import InputError
from ocalib.geometry.alignment import align_trajectory
from ocalib.geometry.se3 import invert, rotation_angle_deg, so3_log


def rotation_gain(pred: np.ndarray, truth: np.ndarray, min_rms_deg: float = 0.01) -> np.ndarray:
    """How much of the true rotation a predictor reports, about each camera axis: from frame-to-frame motions
    (N, 4, 4) predicted and true, the least-squares ``g_i`` of ``r_pred,i = g_i r_true,i`` over the rotation
    vectors' components i = x, y, z (camera frame) -> (3,). 1 is unbiased; below 1 the predictor under-reports
    the rotation (a pose network short of training regresses toward no motion). NaN about an axis whose true
    rotation is below ``min_rms_deg`` RMS (nothing to measure). Different gains per axis bend the rotation axes,
    which biases hand-eye calibration even where the per-frame errors are small."""
    rp, rt = so3_log(pred[:, :3, :3]), so3_log(truth[:, :3, :3])
    power = (rt * rt).sum(0)
    excited = np.sqrt(power / len(rt)) > np.radians(min_rms_deg)
    return np.where(excited, (rp * rt).sum(0) / np.where(excited, power, 1.0), np.nan)


def frame_motions(poses: np.ndarray, delta: int = 1) -> np.ndarray:
    """Motions ``P_t^-1 P_{t+delta}`` (N - delta, 4, 4) of a trajectory (N, 4, 4)."""
    return invert(poses[:-delta]) @ poses[delta:]


def congruence_residual(trajectories: np.ndarray, min_angle_deg: float = 0.05) -> float:
    """How far a rig's cameras' motions are from turning by one angle every frame, as every rigid rig's must (the
    screw congruence: ``angle(A) = angle(B)`` whatever the extrinsic), with no truth: for trajectories (T, C, 4, 4)
    (camera 0 first), per camera k >= 1 ``sum |a0 - ak| / sum (a0 + ak) / 2`` over the frame-to-frame rotation
    angles of the frames where either turns by ``min_angle_deg`` or more, the median over k. 0 is congruent; a
    common gain of every camera's rotation does not change it. NaN where no frame turns."""
    angles = np.stack([rotation_angle_deg(frame_motions(trajectories[:, c])[:, :3, :3])
                       for c in range(trajectories.shape[1])], 1)  # fmt: skip
    residuals = []
    for k in range(1, angles.shape[1]):
        a0, ak = angles[:, 0], angles[:, k]
        turning = np.isfinite(a0) & np.isfinite(ak) & (np.maximum(a0, ak) >= min_angle_deg)
        total = (a0[turning] + ak[turning]).sum() / 2
        residuals.append(np.abs(a0[turning] - ak[turning]).sum() / total if total > 0 else np.nan)
    return float(np.median(residuals)) if residuals else float("nan")


def snippet_ate(pred: np.ndarray, gt: np.ndarray, length: int = 5) -> np.ndarray:
    """SfMLearner's snippet ATE of every window of ``length`` consecutive frames -> (N - length + 1,).

    As SfMLearner's ``kitti_eval`` (``compute_ate``): both snippets re-referenced to their first frame,
    positions only, the prediction scaled by the least-squares factor ``sum(g . p) / sum(p . p)``, and the
    error ``||s p - g||_F / length`` (the Frobenius norm over the snippet divided by its length, *not* an RMSE).
    Here the snippet's predicted poses are the chained frame-to-frame predictions.
    """
    if len(pred) < length:
        raise InputError(f"snippet ATE needs at least {length} frames, got {len(pred)}")
    out = []
    for i in range(len(pred) - length + 1):
        p = (invert(pred[i]) @ pred[i : i + length])[:, :3, 3]
        g = (invert(gt[i]) @ gt[i : i + length])[:, :3, 3]
        norm = (p * p).sum()
        scale = (g * p).sum() / norm if norm > 0 else 0.0
        out.append(np.linalg.norm(scale * p - g) / length)
    return np.asarray(out)


def rpe(pred: np.ndarray, gt: np.ndarray, delta: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Relative pose errors over ``delta`` frames of aligned predicted poses -> translation (M,), rotation deg (M,).

    ``E_i = (G_i^-1 G_{i+delta})^-1 (P_i^-1 P_{i+delta})`` (Sturm et al., TUM RGB-D); its translation norm
    (ground-truth units once ``pred`` is Sim(3)-aligned) and rotation angle.
    """
    E = invert(frame_motions(gt, delta)) @ frame_motions(pred, delta)
    return np.linalg.norm(E[:, :3, 3], axis=1), rotation_angle_deg(E[:, :3, :3])


def motion_errors(pred: np.ndarray, gt: np.ndarray, moving: np.ndarray | None = None) -> dict:
    """Errors of predicted motions (M, 4, 4) against the true ones (M, 4, 4), motion by motion.

    ``rotation_deg``: angle of ``R_gt^T R_pred``. ``direction_deg``: angle between predicted and true translation
    (90 where the prediction has none). ``scale_ratio``: ``|t_pred| / |t_gt|``. Direction and ratio are NaN where
    ``moving`` (M,) is False (default: where the true translation is zero).
    """
    rot = rotation_angle_deg(np.swapaxes(gt[:, :3, :3], 1, 2) @ pred[:, :3, :3])
    tp, tg = pred[:, :3, 3], gt[:, :3, 3]
    np_, ng = np.linalg.norm(tp, axis=1), np.linalg.norm(tg, axis=1)
    moving = ng > 0 if moving is None else np.asarray(moving, bool)
    cos = np.where(np_ > 0, (tp * tg).sum(1) / np.maximum(np_ * ng, 1e-300), 0.0)
    direction = np.degrees(np.arccos(np.clip(cos, -1, 1)))
    return {
        "rotation_deg": rot,
        "direction_deg": np.where(moving, direction, np.nan),
        "scale_ratio": np.where(moving, np_ / np.maximum(ng, 1e-300), np.nan),
        "moving": moving,
    }


def frame_errors(pred: np.ndarray, gt: np.ndarray, min_translation: float = 1e-3, min_fraction: float = 0.1) -> dict:
    """:func:`motion_errors` of the frame-to-frame motions (N - 1) of trajectories (N, 4, 4); ``moving``: frames
    whose true translation exceeds ``max(min_translation, min_fraction * median)`` (a direction or ratio of a tiny
    motion is noise)."""
    mp, mg = frame_motions(pred), frame_motions(gt)
    ng = np.linalg.norm(mg[:, :3, 3], axis=1)
    return motion_errors(mp, mg, ng > max(min_translation, min_fraction * float(np.median(ng))))


def step_errors(pred: np.ndarray, gt: np.ndarray, valid: np.ndarray | None = None, gap: int = 1) -> dict:
    """What the hand-eye calibration needs from a front end: :func:`motion_errors` of the motions over ``gap``
    frames of trajectories (N, 4, 4), where ``valid`` (N,) marks frames whose motion from the previous frame has a
    translation (a motion counts when every frame in it is valid; ``valid`` (N - gap,) in the output, and
    ``direction_deg`` and ``scale_ratio`` over the valid motions only), plus ``scale_cv``: the coefficient of
    variation of ``scale_ratio`` over the valid motions (std / mean, which no global scale changes; NaN with
    fewer than two)."""
    ok = np.ones(len(pred) - gap, bool)
    if valid is not None:
        v = np.asarray(valid, bool)
        ok = np.stack([v[1 + i : len(v) - gap + 1 + i] for i in range(gap)]).all(0)
    out = motion_errors(frame_motions(pred, gap), frame_motions(gt, gap), ok)
    ratio = out["scale_ratio"] = out["scale_ratio"][ok]
    out["direction_deg"], out["valid"] = out["direction_deg"][ok], out.pop("moving")
    out["scale_cv"] = float(ratio.std() / ratio.mean()) if len(ratio) > 1 and ratio.mean() > 0 else float("nan")
    return out


def pose_metrics(
    pred: np.ndarray,
    gt: np.ndarray,
    rpe_delta: int = 1,
    snippet: int = 5,
    min_translation: float = 1e-3,
    min_fraction: float = 0.1,
) -> tuple[dict, dict]:
    """All pose metrics of a predicted trajectory against ground truth, both (N, 4, 4) camera-to-world.

    Returns (summary, details): summary holds scalars for the JSON; details the aligned predicted poses
    (``aligned``, (N, 4, 4)), the per-frame arrays of :func:`frame_errors`, the snippet ATEs and the RPE
    arrays, for plots. Raises InputError when the ground truth has no motion (nothing to measure against).
    """
    pred = np.asarray(pred, dtype=np.float64)
    gt = np.asarray(gt, dtype=np.float64)
    if pred.shape != gt.shape or pred.ndim != 3 or pred.shape[1:] != (4, 4) or len(pred) < 2:
        raise InputError(
            f"pose metrics need two (N >= 2, 4, 4) trajectories of equal length, got {pred.shape} and {gt.shape}"
        )
    frames = frame_errors(pred, gt, min_translation, min_fraction)
    moving = frames["moving"]
    if not moving.any():
        raise InputError(
            f"the ground-truth trajectory of {len(gt)} frames does not move (every frame-to-frame "
            f"translation <= {min_translation:g}): pose errors are undefined"
        )
    aligned, sim3 = align_trajectory(pred, gt)
    ate = np.linalg.norm(aligned[:, :3, 3] - gt[:, :3, 3], axis=1)
    rpe_t, rpe_r = rpe(aligned, gt, rpe_delta) if len(gt) > rpe_delta else (np.array([np.nan]),) * 2
    snip = snippet_ate(pred, gt, snippet) if len(gt) >= snippet else np.array([np.nan])
    ratio = frames["scale_ratio"][moving]
    direction = frames["direction_deg"][moving]
    rot = frames["rotation_deg"]
    truth = frame_motions(gt)
    steps = np.linalg.norm(truth[:, :3, 3], axis=1)
    baseline = trivial_baselines(truth, moving)
    summary = {
        "frames": len(gt),
        "moving_frames": int(moving.sum()),
        "path_length": float(steps.sum()),
        f"sfmlearner_{snippet}frame_snippet_ate": float(np.mean(snip)),
        f"sfmlearner_{snippet}frame_snippet_ate_std": float(np.std(snip)),
        "ate_rmse": float(np.sqrt(np.mean(ate**2))),
        "ate_sim3_scale": float(sim3["scale"]),
        "rpe_delta": rpe_delta,
        "rpe_trans_rmse": float(np.sqrt(np.mean(rpe_t**2))),
        "rpe_rot_rmse_deg": float(np.sqrt(np.mean(rpe_r**2))),
        "rotation_error_deg_median": float(np.median(rot)),
        "rotation_error_deg_mean": float(np.mean(rot)),
        "direction_error_deg_median": float(np.median(direction)),
        "direction_error_deg_mean": float(np.mean(direction)),
        "scale_ratio_median": float(np.median(ratio)),
        "scale_ratio_cv": float(np.std(ratio) / np.mean(ratio)) if np.mean(ratio) > 0 else float("inf"),
        "rotation_gain_xyz": [float(g) for g in rotation_gain(frame_motions(pred), truth)],
        **baseline,
    }
    details = {
        "aligned": aligned,
        "sim3": sim3,
        "ate": ate,
        "rpe_trans": rpe_t,
        "rpe_rot_deg": rpe_r,
        "snippet_ate": snip,
        **frames,
    }
    return summary, details


def trivial_baselines(truth: np.ndarray, moving: np.ndarray) -> dict:
    """The frame-to-frame metrics of predictors that ignore the images, for scale: given the true motions
    (N - 1, 4, 4) and the ``moving`` mask of :func:`frame_errors`.

    ``baseline_zero_rotation_deg_median/mean``: rotation error of a predictor that never rotates (the true
    angles). ``baseline_constant_direction_deg_median``: direction error of the best fixed direction (the
    normalised mean of the true unit directions). ``baseline_constant_step_scale_cv``: scale-ratio CV of
    steps of constant length (the CV of 1 / |t_gt|).
    """
    angles = rotation_angle_deg(truth[:, :3, :3])
    t = truth[moving, :3, 3]
    units = t / np.linalg.norm(t, axis=1, keepdims=True)
    mean = units.mean(0)
    cos = units @ (mean / max(np.linalg.norm(mean), 1e-300))
    inv = 1 / np.linalg.norm(t, axis=1)
    return {
        "baseline_zero_rotation_deg_median": float(np.median(angles)),
        "baseline_zero_rotation_deg_mean": float(np.mean(angles)),
        "baseline_constant_direction_deg_median": float(np.median(np.degrees(np.arccos(np.clip(cos, -1, 1))))),
        "baseline_constant_step_scale_cv": float(inv.std() / inv.mean()),
    }
