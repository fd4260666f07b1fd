"""Evaluating predictions against a sequence's ground truth: depth maps and poses, per camera.

:func:`evaluate_stream` consumes :class:`~ocalib.inference.predict.FramePrediction` s from any source (the model
through :func:`evaluate_model`, or ground truth in the tests) and measures, per camera, the depth metrics of
:mod:`ocalib.eval.depth_metrics` and the pose metrics of :mod:`ocalib.eval.pose_metrics`, on whatever ground
truth the sequence has.

Convention: predicted depth is compared with the ground truth inside the view's crop at the ground truth's
resolution (the predicted disparity resized bilinearly); ground-truth poses are re-referenced to their first
frame (every pose metric is invariant to that choice), so aligned predictions live in that frame.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from ocalib.data.image_io import read_depth
from ocalib.data.model_view import ModelView, model_view
from ocalib.data.sequence import Camera, Sequence
from ocalib.errors import InputError
from ocalib.eval.depth_metrics import depth_errors, mean_depth_errors
from ocalib.eval.pose_metrics import pose_metrics
from ocalib.geometry.se3 import chain_motions, invert
from ocalib.inference.predict import FramePrediction, PredictOptions, predict_frames
from ocalib.io.jsonable import finite_or_null


@dataclass
class CameraEvaluation:
    """One camera's results. poses: predicted (N, 4, 4) camera-to-first-frame, network units; truth: ground-truth
    poses re-referenced to the first frame, or None; depth / pose: metric summaries (None without that ground
    truth); per_image: per-frame depth metrics (None where no pixel was valid); details: see
    :func:`~ocalib.eval.pose_metrics.pose_metrics`."""

    name: str
    poses: np.ndarray
    truth: np.ndarray | None = None
    depth: dict | None = None
    per_image: list = field(default_factory=list)
    pose: dict | None = None
    details: dict | None = None
    missing: list[str] = field(default_factory=list)


def ground_truth_available(sequence: Sequence) -> dict[str, list[str]]:
    """Camera name -> the kinds of ground truth it lacks (``depth``, ``poses``). Raises InputError when no
    camera has any, naming what is missing."""
    missing = {
        cam.name: [k for k, v in (("depth", cam.depth), ("poses", cam.poses)) if v is None] for cam in sequence.cameras
    }
    if all(len(m) == 2 for m in missing.values()):
        raise InputError(
            f"{sequence.path}: nothing to evaluate against: the sequence ({sequence.layout} layout) has "
            f"no ground-truth depth maps and no ground-truth poses for camera(s) {', '.join(missing)}; "
            "use `ocalib predict` for predictions alone"
        )
    return missing


def depth_against_truth(
    pred: np.ndarray, camera: Camera, view: ModelView, t: int, min_depth: float, max_depth: float
) -> dict | None:
    """Depth metrics of a predicted map (H, W) (network units, model resolution) against frame t's ground truth."""
    x0, y0, w, h = view.crop
    gt = read_depth(camera.depth[t], camera.depth_scale, camera.size)[0].numpy()[y0 : y0 + h, x0 : x0 + w]
    if pred.shape != gt.shape:
        disparity = cv2.resize(1.0 / np.maximum(pred, 1e-12), (w, h), interpolation=cv2.INTER_LINEAR)
        pred = 1.0 / np.maximum(disparity, 1e-12)
    return depth_errors(pred, gt, min_depth, max_depth)


def evaluate_stream(
    sequence: Sequence,
    frames: Iterable[FramePrediction],
    views: list[ModelView],
    min_depth: float = 1e-3,
    max_depth: float = 80.0,
    rpe_delta: int = 1,
    min_translation: float = 1e-3,
) -> list[CameraEvaluation]:
    """Measure the predictions ``frames`` (every frame of ``sequence`` in order; C cameras as in the sequence,
    seen through ``views``) against the ground truth -> one :class:`CameraEvaluation` per camera.

    Depth maps are compared as they arrive (none is kept); ``min_depth``/``max_depth`` cap the ground truth
    (metres); ``rpe_delta``: the RPE frame gap; ``min_translation``: ground-truth motions shorter than this
    (and than a tenth of the median) give no translation direction or scale ratio.
    """
    missing = ground_truth_available(sequence)
    cams = sequence.cameras
    per_image = [[] for _ in cams]
    motions = []
    for frame in frames:
        motions.append(frame.motion)
        for k, cam in enumerate(cams):
            if cam.depth is not None and frame.depth is not None:
                per_image[k].append(
                    depth_against_truth(frame.depth[k], cam, views[k], frame.frame, min_depth, max_depth)
                )
    if len(motions) != len(sequence):
        raise InputError(f"{sequence.path}: predictions for {len(motions)} of {len(sequence)} frames")
    motions = np.stack(motions, 1)
    results = []
    for k, cam in enumerate(cams):
        result = CameraEvaluation(cam.name, chain_motions(motions[k][1:]), missing=list(missing[cam.name]))
        if per_image[k]:
            result.per_image = per_image[k]
            result.depth = mean_depth_errors(per_image[k]) | {"min_depth": min_depth, "max_depth": max_depth}
        elif cam.depth is not None:
            result.missing.append("depth (predictions made without depth)")
        if cam.poses is not None:
            result.truth = invert(cam.poses[0]) @ cam.poses
            try:
                result.pose, result.details = pose_metrics(
                    result.poses, result.truth, rpe_delta, min_translation=min_translation
                )
            except InputError as err:
                raise InputError(f"{cam.name}: {err}") from None
        results.append(result)
    return results


def evaluate_model(
    model, sequence: Sequence, device="cpu", predict: PredictOptions = PredictOptions(), progress=False, **options
) -> list[CameraEvaluation]:
    """Predict with ``model`` (:func:`predict_frames`; depth only where the sequence has ground truth of it) and
    evaluate (``options``: those of :func:`evaluate_stream`)."""
    missing = ground_truth_available(sequence)
    predict = replace(predict, depth=any("depth" not in m for m in missing.values()))
    views = [model_view(cam, model.height, model.width) for cam in sequence.cameras]
    frames = predict_frames(model, sequence, device, predict, progress)
    return evaluate_stream(sequence, frames, views, **options)


def evaluation_json(results: list[CameraEvaluation]) -> dict:
    """The per-camera JSON document (``cameras``: name -> depth, pose, missing) and ``warnings``; NaN -> null."""
    doc = {"cameras": {}, "warnings": []}
    for r in results:
        doc["cameras"][r.name] = {
            "frames": len(r.poses),
            "depth": finite_or_null(r.depth),
            "pose": finite_or_null(r.pose),
            "missing": r.missing,
        }
        if r.missing:
            done = [k for k, v in (("depth", r.depth), ("pose", r.pose)) if v is not None]
            doc["warnings"].append(
                f"camera {r.name}: no ground-truth {' or '.join(r.missing)}; evaluated: {', '.join(done) or 'nothing'}"
            )
    return doc
