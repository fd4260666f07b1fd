"""Frame-to-frame errors of a trajectory against ground truth: what the hand-eye calibration needs from a
front end (rotations, translation directions, one consistent scale).

Convention: poses (N, 4, 4) camera-to-world (any world frame and unit for the prediction); motions
``T_prev_cur = inv(pose[t-1]) @ pose[t]``.
"""

from __future__ import annotations

import numpy as np


def relative_motions(poses: np.ndarray, gap: int = 1) -> np.ndarray:
    """``inv(pose[t-gap]) @ pose[t]`` for t = gap..N-1: (N - gap, 4, 4)."""
    return np.linalg.inv(poses[:-gap]) @ poses[gap:]


def rotation_angle_deg(R: np.ndarray) -> np.ndarray:
    """Angle (...,) in degrees of rotations R (..., 3, 3)."""
    cos = (np.trace(R, axis1=-2, axis2=-1) - 1) / 2
    sin = 0.5 * np.linalg.norm(np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0],
                                         R[..., 1, 0] - R[..., 0, 1]], -1), axis=-1)  # fmt: skip
    return np.degrees(np.arctan2(sin, cos))  # precise near 0, unlike arccos


def motion_errors(pred: np.ndarray, gt: np.ndarray, valid: np.ndarray | None = None, gap: int = 1) -> dict:
    """Per-motion errors of predicted poses (N, 4, 4) against ground truth (N, 4, 4).

    valid: (N,) bool, frames whose motion from the previous frame has a translation (non-degenerate);
    a motion over ``gap`` frames counts when every frame in it is valid. Returns arrays over the motions:
    ``rotation_deg`` (all motions), and over the valid ones ``direction_deg`` (angle between translations)
    and ``ratio`` (|t_pred| / |t_gt|); ``scale_cv``: the coefficient of variation of ``ratio`` (std / mean,
    which no global scale changes), NaN with fewer than two valid motions.
    """
    mp, mg = relative_motions(pred, gap), relative_motions(gt, gap)
    rot = rotation_angle_deg(np.swapaxes(mp[:, :3, :3], 1, 2) @ mg[:, :3, :3])
    ok = np.ones(len(mp), bool)
    if valid is not None:
        v = np.asarray(valid, bool)
        ok = np.stack([v[1 + i : len(v) - gap + 1 + i] for i in range(gap)]).all(0)
    tp, tg = mp[ok, :3, 3], mg[ok, :3, 3]
    np_, ng = np.linalg.norm(tp, axis=1), np.linalg.norm(tg, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos = (tp * tg).sum(1) / (np_ * ng)
        ratio = np_ / ng
    direction = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    cv = float(ratio.std() / ratio.mean()) if len(ratio) > 1 and ratio.mean() > 0 else float("nan")
    return {"rotation_deg": rot, "direction_deg": direction, "ratio": ratio, "scale_cv": cv, "valid": ok}
