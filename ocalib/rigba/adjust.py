"""The joint rig bundle adjustment: every camera's feature tracks explained by one rig trajectory and the rig's
extrinsics, so the translation between cameras is recovered where each camera's monocular scale cannot give it.

:func:`adjust_rig` builds a COLMAP workspace of the sequence (:mod:`ocalib.rigba.workspace`), maps it with the rig's
``sensor_from_rig`` started from the on-line head's rotation and refined in every bundle adjustment
(:mod:`ocalib.rigba.mapping`), reads camera k's extrinsic with its uncertainty (:mod:`ocalib.rigba.covariance`),
expresses it in metres (a Sim(3) fit of camera 0's reconstructed trajectory to a metric one, after a last
adjustment with that trajectory's positions as priors where its noise is given: :mod:`ocalib.rigba.metric_prior`) or
in camera 0's front-end units, and checks the result. What goes wrong is said: a camera whose frames do not register, a
reconstruction in pieces or drifting, a rotation moved far from the head's. Such a camera keeps the head's estimate.

Convention: ``T_cam0_camk`` (``p_cam0 = R p_camk + t``); trajectories are camera-to-world (N, 4, 4); the scale
multiplies camera k's front-end units into camera 0's.
"""

from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path

import numpy as np
import pycolmap
from tqdm import tqdm

from ocalib.data.sequence import Sequence
from ocalib.errors import InputError
from ocalib.geometry.alignment import trajectory_scale, umeyama
from ocalib.rigba.colmap import camera_to_world, pinhole_equivalent, to_matrix
from ocalib.rigba.covariance import extrinsic_uncertainty
from ocalib.rigba.lens_check import radial_residuals
from ocalib.rigba.mapping import map_rig
from ocalib.rigba.metric_prior import adjust_with_metric_held, adjust_with_metric_prior
from ocalib.rigba.options import BundleOptions, MapperOptions
from ocalib.rigba.result import RigAdjustment
from ocalib.rigba.trust import checks
from ocalib.rigba.workspace import Workspace, camera_and_frame, create_workspace

MAX_HELD_ERROR_RATIO = 1.5  # the reprojection error with the metric trajectory held, at most this times the free one


def adjust_rig(
    sequence: Sequence,
    initial: np.ndarray,
    frames: int | None = None,
    front_end: np.ndarray | None = None,
    metric: np.ndarray | None = None,
    options: BundleOptions = BundleOptions(),
    workdir: str | Path | None = None,
    every: int | None = None,
    progress: bool | None = None,
    check_rotation: np.ndarray | None = None,
    estimator: np.ndarray | None = None,
) -> RigAdjustment:
    """Refine the extrinsics ``initial`` (C, 4, 4) of ``sequence``'s cameras by a joint rig bundle adjustment over its
    first ``frames`` frames (all by default).

    Only ``initial``'s rotations are used (its translations are in another unit); the lever arms start at zero.
    ``front_end`` (T, C, 4, 4): each camera's front-end trajectory (the units of the result and the scale; optional);
    ``metric`` (T, 4, 4): camera 0's trajectory in metres (then the result is in metres). ``every``: streaming, the
    stage runs after every ``every`` frames on the frames so far (features and matches kept between runs), and
    ``stats["stream"]`` holds each run's frame, extrinsics and seconds. ``workdir``: keep the COLMAP workspace there
    (default: a temporary folder, removed). progress: a bar over the runs (None: on a terminal). check_rotation (C,)
    bool: the cameras whose initial rotation is an estimate the result must stay near (default all; the head's
    unobservable rotations are not). estimator (C, 4, 4): the on-line rig estimator's final extrinsics, where it ran
    (a result near its rotation is trusted too; one far from it is said: :func:`ocalib.rigba.trust.checks`).
    """
    start = time.perf_counter()
    frames = len(sequence) if frames is None else min(frames, len(sequence))
    index = np.arange(0, frames, max(1, options.keyframe_step))
    ends = [frames] if not every else sorted({*range(every, frames, every), frames})
    rig_init = np.array(initial, dtype=np.float64)
    rig_init[1:, :3, 3] = 0.0
    stream = []
    with tempfile.TemporaryDirectory(prefix="ocalib-rigba-") as tmp:
        ws = create_workspace(Path(workdir) if workdir is not None else Path(tmp), sequence, rig_init, options.features)
        for end in tqdm(ends, desc="bundle adjustment", unit="run", disable=None if progress is None else not progress):
            run_start = time.perf_counter()
            out = _solve(ws, index[index < end], initial, front_end, metric, options.mapper, check_rotation, estimator)
            stream.append(
                {
                    "frame": end,
                    "extrinsics": out.extrinsics[1:].tolist(),
                    "trusted": out.trusted[1:].tolist(),
                    "seconds": time.perf_counter() - run_start,
                }
            )
    out.stats.update(seconds=time.perf_counter() - start, **{f"{k}_seconds": v for k, v in ws.seconds.items()})
    out.stats.update(threads=options.mapper.threads, repeatable=options.mapper.threads == options.features.threads == 1)
    if every:
        out.stats["stream"] = stream
    return out


def _solve(
    ws: Workspace,
    index: np.ndarray,
    initial: np.ndarray,
    front_end: np.ndarray | None,
    metric: np.ndarray | None,
    options: MapperOptions,
    check_rotation: np.ndarray | None,
    estimator: np.ndarray | None,
) -> RigAdjustment:
    """Add the frames ``index`` to ``ws``, map them and read the result, checked against the on-line estimates (see
    :func:`adjust_rig`)."""
    ws.add_frames(index.tolist())
    start = time.perf_counter()
    models = map_rig(ws, options)
    metric_stats, metric_warnings = _metric_inside(models, ws, metric, options) if models else ({}, [])
    mapping = time.perf_counter() - start
    keypoints = _median_keypoints(ws.database)
    if not models:
        out = _failed(
            ws.sequence,
            initial,
            index,
            [
                f"bundle adjustment: no reconstruction from the images ({keypoints:.0f} keypoints an image, median; "
                "textureless images, too little motion, or wrong intrinsics?); the on-line estimate is kept"
            ],
        )
    else:
        out = _read(models[0], ws, index, front_end, metric)
        check = np.ones(len(initial), bool) if check_rotation is None else np.asarray(check_rotation, bool)
        head = np.where(check[:, None, None], initial, np.nan)
        out.warnings = checks(out, ws.sequence, head, models, keypoints, estimator) + metric_warnings + out.warnings
    out.stats.update(
        models=len(models),
        keypoints_median=keypoints,
        mapping_seconds=mapping,
        **metric_stats,
        registered_frames_other_models=[m.num_reg_frames() for m in models[1:]],
    )
    return out


def _metric_inside(
    models: list[pycolmap.Reconstruction], ws: Workspace, metric: np.ndarray | None, options: MapperOptions
) -> tuple[dict, list[str]]:
    """The metric trajectory inside the adjustment of ``models[0]`` (replaced in place): held (``metric_noise`` 0)
    where the images agree with it (the reprojection error held at most ``MAX_HELD_ERROR_RATIO`` times the free
    one; else the free reconstruction is kept, with a warning), or its positions as priors -> stats, warnings."""
    if metric is None or options.metric_noise is None:
        return {"metric_inside": None}, []
    frame_of = {i: camera_and_frame(image.name)[1] for i, image in models[0].images.items()}
    if options.metric_noise > 0:
        done = adjust_with_metric_prior(models[0], ws.camera_ids[0], frame_of, metric, options.metric_noise,
                                        options.threads)  # fmt: skip
        return {"metric_inside": "priors" if done else None, "metric_prior_noise_m": options.metric_noise}, []
    held = adjust_with_metric_held(models[0], frame_of, metric, options.threads)
    if held is None:
        return {"metric_inside": None}, []
    models[0].update_point_3d_errors()
    free, fixed = models[0].compute_mean_reprojection_error(), held.compute_mean_reprojection_error()
    stats = {"reprojection_free_px": free, "reprojection_held_px": fixed}
    if not fixed <= MAX_HELD_ERROR_RATIO * free:
        return stats | {"metric_inside": None}, [
            f"bundle adjustment: the images disagree with the metric trajectory held fixed (reprojection error "
            f"{fixed:.2f} px against {free:.2f} px free): its poses are off (time stamps, camera 0's frame, noise?); "
            "the reconstruction is scaled to it instead"
        ]
    models[0] = held
    return stats | {"metric_inside": "held"}, []


def _read(
    rec: pycolmap.Reconstruction,
    ws: Workspace,
    index: np.ndarray,
    front_end: np.ndarray | None,
    metric: np.ndarray | None,
) -> RigAdjustment:
    """The extrinsics, trajectories and uncertainty of the reconstruction ``rec``, in metres or front-end units."""
    C = len(ws.sequence.cameras)
    camera_ids = ws.camera_ids
    rig = next(iter(rec.rigs.values()))
    extrinsics = np.stack(
        [np.eye(4)] + [np.linalg.inv(to_matrix(rig.sensor_from_rig(_sensor(cid)))) for cid in camera_ids[1:]]
    )
    poses = np.full((len(index), C, 4, 4), np.nan)
    row = {int(t): i for i, t in enumerate(index)}
    for image in rec.images.values():
        if image.has_pose:
            k, t = camera_and_frame(image.name)
            poses[row[t], k] = camera_to_world(image)
    registered = ~np.isnan(poses[:, :, 0, 0])
    start = time.perf_counter()
    pinhole = pinhole_equivalent(rec)
    try:
        uncertainty = extrinsic_uncertainty(pinhole, camera_ids)
    except np.linalg.LinAlgError:
        uncertainty = [None] * (C - 1)
    seconds = time.perf_counter() - start
    radial = radial_residuals(pinhole)
    units, scale, warnings = "reconstruction", 1.0, []
    ok = registered[:, 0]
    reference = metric if metric is not None else (front_end[:, 0] if front_end is not None else None)
    if reference is not None and ok.sum() >= 3:
        try:
            scale, R, t = umeyama(poses[ok, 0, :3, 3], reference[index[ok], :3, 3])
            units = "metres" if metric is not None else "camera 0's front-end units"
        except InputError as err:
            warnings.append(
                f"bundle adjustment: cannot scale the translation ({err}); it is in the reconstruction's units"
            )
    extrinsics[:, :3, 3] *= scale
    poses[..., :3, 3] *= scale
    for u in uncertainty:
        if u is not None:
            u.covariance[3:, :] *= scale
            u.covariance[:, 3:] *= scale
    out = RigAdjustment(
        extrinsics=extrinsics,
        trusted=np.ones(C, bool),
        uncertainty=[None] + uncertainty,
        scale=_camera_scales(poses, registered, front_end, index),
        frames=index,
        trajectory=poses[:, 0],
        registered=registered,
        units=units,
        warnings=warnings,
    )
    out.stats = {
        "registered_frames": int(rec.num_reg_frames()),
        "frames": len(index),
        "points": int(rec.num_points3D()),
        "observations": int(rec.compute_num_observations()),
        "reprojection_error_px": float(rec.compute_mean_reprojection_error()),
        "mean_track_length": float(rec.compute_mean_track_length()),
        "uncertainty_seconds": seconds,
        "radial_residual_corner_px": [radial[cid].corner_px for cid in camera_ids],
        "lens_missing": [radial[cid].significant for cid in camera_ids],
    }
    if metric is not None and units == "metres":
        out.stats["drift"] = _drift(poses[ok, 0, :3, 3], metric[index[ok], :3, 3])
    return out


def _failed(sequence: Sequence, initial: np.ndarray, index: np.ndarray, warnings: list[str]) -> RigAdjustment:
    C = len(sequence.cameras)
    return RigAdjustment(
        extrinsics=np.array(initial, dtype=np.float64),
        trusted=np.eye(1, C, dtype=bool)[0],
        uncertainty=[None] * C,
        scale=np.ones(C),
        frames=index,
        trajectory=np.full((len(index), 4, 4), np.nan),
        registered=np.zeros((len(index), C), bool),
        units="none",
        warnings=warnings,
    )


def _camera_scales(
    poses: np.ndarray, registered: np.ndarray, front_end: np.ndarray | None, index: np.ndarray
) -> np.ndarray:
    """(C,) the scale that multiplies camera k's front-end units into camera 0's, through the one rig trajectory."""
    C = poses.shape[1]
    if front_end is None:
        return np.ones(C)
    ratio = np.full(C, np.nan)
    for k in range(C):
        ok = registered[:, k]
        if ok.sum() >= 3:
            ratio[k] = trajectory_scale(front_end[index[ok], k], np.linalg.inv(poses[ok, k][:1]) @ poses[ok, k])
    return ratio / ratio[0]


def _drift(positions: np.ndarray, metric: np.ndarray) -> float:
    """RMS position error after a Sim(3) fit, over the metric path's length."""
    s, R, t = umeyama(positions, metric)
    error = np.sqrt(np.mean(np.sum((s * positions @ R.T + t - metric) ** 2, axis=1)))
    length = np.sum(np.linalg.norm(np.diff(metric, axis=0), axis=1))
    return float(error / length) if length > 0 else math.inf


def _median_keypoints(database: Path) -> float:
    db = pycolmap.Database.open(database)
    try:
        counts = [db.num_keypoints_for_image(image.image_id) for image in db.read_all_images()]
    finally:
        db.close()
    return float(np.median(counts)) if counts else 0.0


def _sensor(camera_id: int) -> pycolmap.sensor_t:
    return pycolmap.sensor_t(pycolmap.SensorType.CAMERA, camera_id)
