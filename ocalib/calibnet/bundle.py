"""The rig bundle adjustment (:mod:`ocalib.rigba`) as the stage after the on-line pass of ``ocalib calibrate``: it
starts from the head's rotations and the front end's trajectories, and leaves its result beside the head's.

Convention: as :mod:`ocalib.rigba.adjust`; ``metric`` is camera 0's camera-to-world trajectory in metres at the
sequence's frames (T, 4, 4).
"""

from __future__ import annotations

import numpy as np
import torch

from ocalib.calib.drivers.result import planar_axes
from ocalib.calibnet.run import ImageCalibration
from ocalib.errors import InputError
from ocalib.geometry.quaternion import rotation_matrix_to_quaternion
from ocalib.rigba.adjust import adjust_rig
from ocalib.rigba.evaluate import adjustment_errors
from ocalib.rigba.options import BundleOptions


def refine_calibration(
    result: ImageCalibration,
    metric: np.ndarray | None = None,
    options: BundleOptions = BundleOptions(),
    every: int | None = None,
    workdir=None,
    progress: bool | None = None,
) -> ImageCalibration:
    """Run the rig bundle adjustment over the frames ``result`` calibrated; its result and (where the sequence has a
    truth) its errors go into ``result.bundle`` and ``result.bundle_errors``. Returns ``result``."""
    sequence, run = result.sequence, result.run
    if sequence is None:
        raise InputError("the bundle adjustment needs the calibrated sequence's images")
    frames = run.settings["frames"]
    if metric is not None and len(metric) < frames:
        raise InputError(f"the metric trajectory has {len(metric)} poses for {frames} frames")
    C = len(sequence.cameras)
    initial = np.tile(np.eye(4), (C, 1, 1))
    initial[1:, :3, :3] = run.final.rotation[0].double().numpy()
    initial[1:, :3, 3] = run.final.translation[0].double().numpy()
    # The head's rotations the result must stay near: those it observed (directly, or through the planar route).
    known = (run.final.rotation_observable | run.final.planar_motion)[0].numpy()
    result.bundle = adjust_rig(
        sequence,
        initial,
        frames,
        front_end=run.rig.poses,
        metric=None if metric is None else np.linalg.inv(metric[:1]) @ metric[:frames],
        options=options,
        workdir=workdir,
        every=every,
        progress=progress,
        check_rotation=np.concatenate([[True], known]),
        estimator=None if result.rig is None else result.rig.steady_extrinsics(),
    )
    _trace(result)
    if result.truth is not None:
        truth = None
        if all(cam.poses is not None for cam in sequence.cameras):
            truth = np.stack([cam.poses[:frames] for cam in sequence.cameras], 1)
        extrinsics = np.concatenate([np.eye(4)[None], result.truth])
        errors = adjustment_errors(result.bundle, extrinsics, truth, planar_axes(run.final))
        trusted = result.bundle.trusted[1:]  # where the head's estimate is kept, so are its errors
        result.bundle_errors = [e if ok else head for e, head, ok in zip(errors, result.errors, trusted)]
    return result


def _trace(result: ImageCalibration) -> None:
    """The bundle adjustment's extrinsics into the run's trace (``bundle_quaternion`` (F, K, 4), ``bundle_translation``
    (F, K, 3)) at the last frame each run saw, NaN elsewhere and where a camera's result is not trusted."""
    trace, adjustment = result.run.trace, result.bundle
    runs = adjustment.stats.get("stream") or [
        {"frame": len(trace["frame"]), "extrinsics": adjustment.extrinsics[1:], "trusted": adjustment.trusted[1:]}
    ]
    F, K = trace["quaternion"].shape[:2]
    quaternion, translation = np.full((F, K, 4), np.nan), np.full((F, K, 3), np.nan)
    for r in runs:
        E, ok = np.asarray(r["extrinsics"]), np.asarray(r["trusted"])
        q = rotation_matrix_to_quaternion(torch.from_numpy(E[:, :3, :3])).numpy()
        quaternion[r["frame"] - 1] = np.where(ok[:, None], q * np.sign(q[:, :1] + 1e-300), np.nan)
        translation[r["frame"] - 1] = np.where(ok[:, None], E[:, :3, 3], np.nan)
    trace["bundle_quaternion"], trace["bundle_translation"] = quaternion, translation
