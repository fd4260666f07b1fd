"""Errors of a rig calibration against ground truth, in the terms of the paper's simulation.

Convention: ``T_cam0_camk`` (``p_cam0 = R p_camk + t``), metres in the ground truth; the estimate's
translation is in camera 0's front-end units, so it is brought to metres by the scale that aligns
camera 0's estimated trajectory to its ground truth (a Sim(3) fit of the positions).
"""

from __future__ import annotations

import math

import numpy as np

from ocalib.calib.drivers.result import Calibration, planar_axes
from ocalib.eval.pose_metrics import frame_motions, rotation_gain
from ocalib.geometry.alignment import trajectory_scale
from ocalib.geometry.directions import angle_deg, projector_without
from ocalib.geometry.se3 import rotation_angle_deg


def front_end_rotation_gain(estimate: np.ndarray, truth: np.ndarray) -> list[float]:
    """Rotation gain (3,) about each camera axis of a front-end trajectory (T, 4, 4) against the truth (T, 4, 4),
    over the frame-to-frame motions where both are finite (NaN: nothing to measure)."""
    m, g = frame_motions(estimate), frame_motions(truth)
    ok = np.isfinite(m).all((1, 2)) & np.isfinite(g).all((1, 2))
    return [float(x) for x in rotation_gain(m[ok], g[ok])] if ok.sum() >= 2 else [math.nan] * 3


WANDER_WINDOW = 25  # frames, about a turn of the held-out cars


def step_length_errors(trajectory: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per step of cameras 0 and k: ``e`` (N, 2), the log ratio of the front end's step length to the true one, and
    ``lever`` (N,), the log ratio of camera k's true step length to camera 0's.

    ``trajectory``, ``truth`` (T, 2, 4, 4): cameras 0 and k, camera-to-first-frame (the truth in any world frame).
    Steps whose true length is under 0.3x the camera's median, or whose estimate is not finite and positive, are
    left out (N <= T - 1).
    """
    step = lambda P: np.linalg.norm(frame_motions(P)[..., :3, 3], axis=-1)  # noqa: E731
    est = np.stack([step(trajectory[:, c]) for c in range(2)], 1)
    true = np.stack([step(truth[:, c]) for c in range(2)], 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        kept = np.isfinite(est).all(1) & (est > 0).all(1) & (true > 0.3 * np.nanmedian(true, 0)).all(1)
        return np.log(est[kept] / true[kept]), np.log(true[kept, 1] / true[kept, 0])


def scale_wander(trajectory: np.ndarray, truth: np.ndarray, window: int = WANDER_WINDOW) -> tuple[float, float]:
    """How much camera k's front-end scale wanders against camera 0's, beside the signal that hides in it.

    ``trajectory``, ``truth``: as :func:`step_length_errors`. Returns (*wander*, *signal*): the std of the
    ``window``-frame moving mean of ``e_k - e_0``, and the same of the true steps' length ratio, whose change in
    turns (the lever arm) the rig's translation is solved from. NaN with fewer than ``2 window`` steps kept.
    """
    e, lever = step_length_errors(trajectory, truth)
    if len(e) < 2 * window:
        return math.nan, math.nan
    moving_std = lambda x: float(np.convolve(x - x.mean(), np.ones(window) / window, mode="valid").std())  # noqa: E731
    return moving_std(e[:, 1] - e[:, 0]), moving_std(lever)


def extrinsic_errors(
    estimate: Calibration, extrinsics: np.ndarray, trajectory: np.ndarray, truth: np.ndarray | None
) -> list[dict]:
    """Per camera k >= 1 of rig 0: the errors of ``estimate`` against the true ``extrinsics`` (C, 4, 4).

    ``trajectory`` (T, C, 4, 4): the front end's camera-to-first-frame poses; ``truth`` (T, C, 4, 4) the
    ground-truth poses (any world frame) or None. On planar motion the translation is compared in the
    plane normal to the estimated rotation axis (the component along it is unobservable).

    Keys: ``rotation_error_deg``, ``translation_direction_error_deg``, and with ``truth``:
    ``metric_scale`` (front-end units of camera 0 -> metres), ``translation_error`` (metres, after that
    scale), ``translation_error_rel_baseline`` (over the whole true baseline),
    ``scale_true`` (the scale that maps camera k's front-end units into camera 0's), and
    ``rotation_gain_reference`` / ``rotation_gain`` (3 each): the front end's rotation gain about each axis of
    camera 0 / camera k (:func:`~ocalib.eval.pose_metrics.rotation_gain`; unequal gains bend the rotation axes),
    ``scale_wander`` / ``lever_arm_signal``: see :func:`scale_wander` (the translation needs the first well under
    the second), over windows of ``wander_window`` frames.
    """
    C = extrinsics.shape[0]
    ref = np.linalg.inv(extrinsics[0])
    rel = ref @ extrinsics  # re-referenced to camera 0
    scales = None
    if truth is not None:
        rebased = np.linalg.inv(truth[:1]) @ truth  # each camera's truth relative to its first frame
        scales = [trajectory_scale(trajectory[:, c], rebased[:, c]) for c in range(C)]
        gains = [front_end_rotation_gain(trajectory[:, c], rebased[:, c]) for c in range(C)]
    axes = planar_axes(estimate)
    out = []
    for k in range(1, C):
        R, t = estimate.rotation[0, k - 1].double().numpy(), estimate.translation[0, k - 1].double().numpy()
        R_gt, t_gt = rel[k, :3, :3], rel[k, :3, 3]
        planar = bool(np.isfinite(axes[k - 1]).all())
        project = projector_without(axes[k - 1])
        baseline = float(np.linalg.norm(t_gt))  # the whole lever arm, whatever is compared
        t, t_gt = project @ t, project @ t_gt
        e = {
            "camera": k,
            "rotation_error_deg": float(rotation_angle_deg(R.T @ R_gt)),
            "translation_direction_error_deg": angle_deg(t, t_gt),
            "compared_in_plane": planar,
        }
        if scales is not None:
            a = scales[0]
            e["metric_scale"] = a
            e["translation_error"] = float(np.linalg.norm(a * t - t_gt))
            e["translation_error_rel_baseline"] = e["translation_error"] / baseline if baseline > 0 else math.nan
            e["scale_true"] = scales[k] / a if a and math.isfinite(a) else math.nan
            e["scale"] = float(estimate.scale[0, k - 1])
            e["rotation_gain_reference"], e["rotation_gain"] = gains[0], gains[k]
            e["scale_wander"], e["lever_arm_signal"] = scale_wander(trajectory[:, [0, k]], truth[:, [0, k]])
            e["wander_window"] = WANDER_WINDOW
        out.append(e)
    return out
