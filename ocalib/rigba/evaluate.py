"""The rig bundle adjustment's extrinsics against the truth (a rendered rig's, or a reference calibration's).

Convention: ``T_cam0_camk`` (``p_cam0 = R p_camk + t``); trajectories are camera-to-world (T, C, 4, 4).
"""

from __future__ import annotations

import math

import numpy as np

from ocalib.geometry.alignment import umeyama
from ocalib.geometry.directions import angle_deg, height_error, projector_without
from ocalib.geometry.se3 import rotation_angle_deg
from ocalib.rigba.result import RigAdjustment


def adjustment_errors(
    adjustment: RigAdjustment, extrinsics: np.ndarray, truth: np.ndarray | None, plane: np.ndarray | None = None
) -> list[dict]:
    """Per camera k >= 1: the bundle-adjusted extrinsic's errors against the true ``extrinsics`` (C, 4, 4), as
    :func:`ocalib.eval.calibration_metrics.extrinsic_errors` gives the head's: ``rotation_error_deg``,
    ``translation_direction_error_deg`` (with the unobservable directions projected out, and on a planar drive the
    ground plane's normal ``plane`` (C - 1, 3), NaN rows elsewhere, see
    :func:`~ocalib.calib.drivers.result.planar_axes`: ``compared_in_plane``; NaN where fewer than two directions
    remain), and
    with ``truth`` (T, C, 4, 4) ground-truth poses: ``metric_scale`` (the result's units -> metres, a Sim(3) fit of
    camera 0's reconstructed trajectory to its truth; 1 in metres), ``translation_error`` (metres),
    ``translation_error_rel_baseline`` (over the whole true lever arm; NaN where no direction is determined) and
    ``height_error`` (:func:`~ocalib.geometry.directions.height_error`)."""
    rel = np.linalg.inv(extrinsics[0]) @ extrinsics
    scale = 1.0
    ok = adjustment.registered[:, 0]
    if truth is not None and adjustment.units != "metres" and ok.sum() >= 3:
        rebased = np.linalg.inv(truth[:1, 0]) @ truth[:, 0]
        scale = umeyama(adjustment.trajectory[ok, :3, 3], rebased[adjustment.frames[ok], :3, 3])[0]
    plane = np.full((len(extrinsics) - 1, 3), np.nan) if plane is None else plane
    out = []
    for k in range(1, len(extrinsics)):
        E, u = adjustment.extrinsics[k], adjustment.uncertainty[k]
        t, t_true = scale * E[:3, 3], rel[k, :3, 3]
        unobservable = u.unobservable if u is not None else np.zeros((0, 3))
        project = projector_without(np.vstack([unobservable, plane[k - 1]]))
        rank = round(float(np.trace(project)))  # a projector's rank (matrix_rank can miss its zero by rounding)
        e = {
            "camera": k,
            "rotation_error_deg": float(rotation_angle_deg(E[:3, :3].T @ rel[k, :3, :3])),
            # A direction needs two observable dimensions to be compared (one left: NaN).
            "translation_direction_error_deg": angle_deg(project @ t, project @ t_true) if rank >= 2 else math.nan,
            "compared_in_plane": rank < 3,
        }
        if truth is not None:
            error = float(np.linalg.norm(project @ (t - t_true))) if rank else math.nan  # nothing determined
            baseline = float(np.linalg.norm(t_true))  # the whole lever arm, whatever is compared
            e.update(
                metric_scale=scale,
                translation_error=error,
                translation_error_rel_baseline=error / baseline if baseline > 0 else math.nan,
                height_error=height_error(t, t_true, plane[k - 1]),
            )
        out.append(e)
    return out
