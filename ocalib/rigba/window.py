"""The sliding window of the on-line rig estimator: its keyframes, their 3-D points, and one bundle adjustment of
them on COLMAP, with every camera's ``sensor_from_rig`` free.

A :class:`Keyframe` holds, per camera, the rig's pose when that camera captured its image (one pose for all where the
cameras are triggered together; the rig's pose at each camera's own capture time where they are not), its features
and the 3-D point each keypoint observes (-1: none). :func:`adjust_window` builds a COLMAP reconstruction of the
window (one rig, camera 0 its reference; intrinsics held), solves for the points and the extrinsics with a robust
loss, drops the observations that stay far off, and returns the extrinsics' uncertainty
(:mod:`ocalib.rigba.covariance`). The rig's poses are either held at the metric trajectory (exact: a render, or
cameras without a shared trigger, each at its own capture pose) or, given the trajectory's noise, solved with the
images, camera 0's metric positions weighted priors (or, where COLMAP cannot align the window to them, the window
anchored at two keyframes: :func:`_adjust_with_priors`): a real trajectory's rotation (GNSS/INS, odometry) is off by
tenths of a degree, pixels at a camera's focal length, which a held window would read as the extrinsics moving.

Convention: poses are the rig's (camera 0's) camera-to-world (4, 4); ``extrinsics`` (C, 4, 4) are ``T_cam0_camk``
(``p_cam0 = R p_camk + t``), the identity for camera 0; keypoints and K in ocalib's pixels (integer centres),
COLMAP's +0.5 added here, once.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pycolmap

from ocalib.geometry.se3 import innovation
from ocalib.rigba.colmap import pinhole_params, to_matrix, to_rigid
from ocalib.rigba.covariance import ExtrinsicUncertainty, Observations, observations_uncertainty
from ocalib.rigba.features import Features
from ocalib.rigba.metric_prior import adjust_with_position_priors
from ocalib.rigba.metric_prior import aligns as metric_aligns

LOSS_SCALE_PX = 1.0  # the Cauchy loss's scale: residuals well above a pixel count less and less
MAX_ERROR_PX = 4.0  # an observation reprojected farther than this after the adjustment is dropped
MIN_SPLIT_OBSERVATIONS = 30  # of a camera before and after a split for :func:`split_statistic`
SPLIT_TRUNCATION = 13.8  # the chi-square's 1e-3 quantile, 2 dof: a squared error counts up to this many variances
MAX_ITERATIONS = 10  # Levenberg-Marquardt iterations a window gets (it starts from the last window's solution)


@dataclass
class Keyframe:
    """One frame of the window: ``frame`` index, ``poses`` (C, 4, 4) the rig's pose when each camera captured its
    image, per camera its ``features`` and ``point_ids`` (N_k,) int64 (the 3-D point each keypoint observes, -1 for
    none); ``prior`` (4, 4) camera 0's pose from the metric trajectory (its position a prior where the window solves
    the poses)."""

    frame: int
    poses: np.ndarray
    features: list[Features]
    point_ids: list[np.ndarray]
    prior: np.ndarray | None = None


@dataclass
class WindowResult:
    """The adjustment's outcome: ``uncertainty`` per camera k >= 1 (None where it could not be computed),
    ``reprojection_px`` the RMS error of the observations kept, ``observations`` their count, ``dropped`` the
    count dropped as outliers; ``trials`` per camera solved apart (:func:`adjust_window`) its extrinsic (4, 4) and
    its points' positions (point id -> (3,)) when the window tries it free; ``priors_used`` where the window solved
    the rig's poses, whether COLMAP took the position priors (:func:`aligns`), None where it held them."""

    uncertainty: list[ExtrinsicUncertainty | None]
    reprojection_px: float
    observations: int
    dropped: int
    trials: dict[int, tuple[np.ndarray, dict[int, np.ndarray]]] = field(default_factory=dict)
    priors_used: bool | None = None


def observations(keyframes: list[Keyframe], points: dict[int, np.ndarray]) -> dict[str, np.ndarray]:
    """The window's observations of points seen at least twice, as arrays: ``camera``, ``frame`` (keyframe
    index), ``keypoint``, ``point`` (index into ``ids``), ``xy`` (N, 2) pixels; ``ids`` (P,) the point ids."""
    camera, frame, keypoint, pid = [], [], [], []
    for i, kf in enumerate(keyframes):
        for k, ids in enumerate(kf.point_ids):
            seen = np.flatnonzero(ids >= 0)
            camera.append(np.full(len(seen), k))
            frame.append(np.full(len(seen), i))
            keypoint.append(seen)
            pid.append(ids[seen])
    camera, frame, keypoint, pid = (np.concatenate(a).astype(np.int64) for a in (camera, frame, keypoint, pid))
    ids, point, counts = np.unique(pid, return_inverse=True, return_counts=True)
    keep = (counts[point] >= 2) & np.isin(pid, list(points))
    xy = np.concatenate([kf.features[k].keypoints for kf in keyframes for k in range(len(kf.features))])
    offsets = np.cumsum([0] + [len(f) for kf in keyframes for f in kf.features])[:-1].reshape(len(keyframes), -1)
    xy = xy[offsets[frame, camera] + keypoint]
    camera, frame, keypoint, pid, xy = camera[keep], frame[keep], keypoint[keep], pid[keep], xy[keep]
    ids, point = np.unique(pid, return_inverse=True)
    return {"camera": camera, "frame": frame, "keypoint": keypoint, "point": point, "xy": xy, "ids": ids}


def reprojection_errors(
    obs: dict[str, np.ndarray], poses: np.ndarray, extrinsics: np.ndarray, xyz: np.ndarray, K: np.ndarray
) -> np.ndarray:
    """(N,) pixel error of each observation of ``obs`` (see :func:`observations`); inf behind the camera.
    poses (N, 4, 4) the rig's at each observation, extrinsics (C, 4, 4), xyz (P, 3), K (C, 3, 3)."""
    cam_from_world = np.linalg.inv(poses @ extrinsics[obs["camera"]])
    p = np.einsum("nij,nj->ni", cam_from_world[:, :3, :3], xyz[obs["point"]]) + cam_from_world[:, :3, 3]
    uv = np.einsum("nij,nj->ni", K[obs["camera"]], p)
    with np.errstate(divide="ignore", invalid="ignore"):
        error = np.linalg.norm(uv[:, :2] / uv[:, 2:] - obs["xy"], axis=1)
    return np.where(p[:, 2] > 1e-9, error, np.inf)


def adjust_window(
    keyframes: list[Keyframe],
    points: dict[int, np.ndarray],
    extrinsics: np.ndarray,
    K: np.ndarray,
    sizes: list[tuple[int, int]],
    held: frozenset[int] = frozenset(),
    prior_noise: float | None = None,
    apart: frozenset[int] = frozenset(),
) -> WindowResult:
    """Bundle-adjust the window in place: ``points`` and ``extrinsics`` (C, 4, 4) (camera 0's stays the identity;
    so do those of the cameras in ``held``). The keyframes' poses are held, or with ``prior_noise`` (metres per
    axis, > 0) solved too where every keyframe's cameras share one pose (:func:`solves_poses`). K (C, 3, 3) and
    ``sizes`` (C,) of (height, width) per camera.

    The cameras in ``apart`` (held ones the window has not determined yet) are solved after the rest, against it:
    the rest without their observations (held where it is not, a camera's misfit would bend the rig's poses and
    every other camera's extrinsic with them), then their points, everything else fixed, and then each of them tried
    free with its points (the result's ``trials``); their residuals do not count in the noise of the uncertainty.
    Outlying observations are dropped from the keyframes afterwards (their ``point_ids`` set to -1)."""
    obs = observations(keyframes, points)
    C = len(extrinsics)
    if not len(obs["ids"]):
        return WindowResult([None] * (C - 1), float("nan"), 0, 0)
    solved = solves_poses(keyframes, prior_noise)
    used = aligns(keyframes, prior_noise) if solved else None
    free = ~np.isin(obs["camera"], list(apart))
    placed = np.bincount(obs["point"], weights=free, minlength=len(obs["ids"])) >= 2  # points the others fix
    first = _subset(obs, placed[obs["point"]] & free)
    if len(first["ids"]):
        xyz, poses = _solve(keyframes, points, extrinsics, K, sizes, first, list(range(C)), held, prior_noise)
        points.update(zip(first["ids"].tolist(), xyz))
        for kf, pose in zip(keyframes, poses):
            kf.poses = pose.copy()
    trials = {}
    if not placed.all():
        trials = _solve_apart(keyframes, points, extrinsics, K, sizes, obs, placed, apart)
    xyz = np.stack([points[int(pid)] for pid in obs["ids"]])
    poses = np.stack([kf.poses for kf in keyframes])
    error = reprojection_errors(obs, poses[obs["frame"], obs["camera"]], extrinsics, xyz, K)
    outlier = ~(error < MAX_ERROR_PX)
    for i, k, j in zip(obs["frame"][outlier], obs["camera"][outlier], obs["keypoint"][outlier]):
        keyframes[i].point_ids[k][j] = -1
    inlier = ~outlier
    uncertainty = _uncertainty(obs, inlier, poses, extrinsics, xyz, K, free, prior_noise if solved else None)
    rms = float(np.sqrt(np.mean(error[inlier] ** 2))) if inlier.any() else float("nan")
    return WindowResult(uncertainty, rms, int(inlier.sum()), int(outlier.sum()), trials, used)


def _solve_apart(keyframes, points, extrinsics, K, sizes, obs, placed, tried):
    """:func:`adjust_window`'s second step: the points the first did not fix (not ``placed`` (P,) bool), everything
    else held (``points`` updated in place); then each camera of ``tried`` free with its points -> per camera tried
    its extrinsic (4, 4) and its points' positions (point id -> (3,)) so solved. Camera 0's observations of placed
    points come along, held: COLMAP leaves a rig's sensors unadjusted where its reference sensor observes nothing."""
    C = len(extrinsics)
    second = _subset(obs, ~placed[obs["point"]] | (placed[obs["point"]] & (obs["camera"] == 0)))
    constant = placed[np.isin(obs["ids"], second["ids"])]
    ids = second["ids"][~constant]
    cameras = frozenset(range(1, C))
    xyz, _ = _solve(keyframes, points, extrinsics, K, sizes, second, list(range(C)), cameras, constant=constant)
    points.update(zip(ids.tolist(), xyz[~constant]))
    trials = {}
    for k in sorted(tried):
        E = extrinsics.copy()
        xyz, _ = _solve(keyframes, points, E, K, sizes, second, list(range(C)), cameras - {k}, constant=constant)
        own = np.isin(ids, obs["ids"][obs["point"][obs["camera"] == k]])
        trials[k] = (E[k], dict(zip(ids[own].tolist(), xyz[~constant][own])))
    return trials


@dataclass
class SplitTest:
    """:func:`split_statistic`'s outcome: the likelihood ratio ``statistic`` and the ``step`` (6,) from the camera's
    extrinsic before to after (rotation vector rad, translation; camera 0's axes; see
    :func:`ocalib.rigba.change.innovation`)."""

    statistic: float
    step: np.ndarray

    @property
    def rotation_deg(self) -> float:
        return float(np.degrees(np.linalg.norm(self.step[:3])))

    @property
    def translation(self) -> float:
        return float(np.linalg.norm(self.step[3:]))


def split_statistic(
    keyframes: list[Keyframe],
    points: dict[int, np.ndarray],
    extrinsics: np.ndarray,
    K: np.ndarray,
    sizes: list[tuple[int, int]],
    camera: int,
    frame: int,
    prior_noise: float | None = None,
) -> SplitTest:
    """The likelihood ratio of camera ``camera`` having moved at ``frame``: the window adjusted with one extrinsic
    for the camera, then from that solution with a second one for its keyframes from ``frame`` on; the fall of the
    truncated squared reprojection errors (``min(e^2, c^2)``, c^2 the chi-square's 1e-3 quantile with 2 degrees of
    freedom over the variance per axis) over that variance. Near chi-square with 6 degrees of freedom where it has
    not moved; the points (and, with ``prior_noise``, the rig's poses: see :func:`adjust_window`) are free in both,
    so resections misled by a few of them, or a trajectory a little off, are not taken for a move. NaN where either
    side has under ``MIN_SPLIT_OBSERVATIONS``. With it, the step from the first extrinsic to the second. Nothing
    given is changed."""
    obs = observations(keyframes, points)
    C = len(extrinsics)
    after = (obs["camera"] == camera) & (np.array([kf.frame for kf in keyframes])[obs["frame"]] >= frame)
    before = (obs["camera"] == camera) & ~after
    if min(after.sum(), before.sum()) < MIN_SPLIT_OBSERVATIONS:
        return SplitTest(float("nan"), np.full(6, np.nan))
    source = list(range(C)) + [camera]
    split = dict(obs, camera=np.where(after, C, obs["camera"]))
    errors, E, points = [], extrinsics.copy(), dict(points)
    for o, sensors in ((obs, source[:C]), (split, source)):
        E = np.concatenate([E, E[camera : camera + 1]]) if len(sensors) > len(E) else E
        xyz, poses = _solve(keyframes, points, E, K[sensors], [sizes[k] for k in sensors], o, sensors,
                            prior_noise=prior_noise)  # fmt: skip
        points.update(zip(obs["ids"].tolist(), xyz))
        poses = poses[obs["frame"], np.array(sensors)[o["camera"]]]  # the rig's at each observation
        errors.append(reprojection_errors(o, poses, E, xyz, K[sensors]) ** 2)
    variance = max(float(np.median(errors[1])) / (2 * np.log(2)), 1e-12)  # per axis: a chi-square's median, 2 dof
    cap = SPLIT_TRUNCATION * variance
    statistic = float((np.minimum(errors[0], cap).sum() - np.minimum(errors[1], cap).sum()) / variance)
    return SplitTest(statistic, innovation(E[camera], E[C]))


def _subset(obs: dict[str, np.ndarray], keep: np.ndarray) -> dict[str, np.ndarray]:
    """The observations ``obs`` (:func:`observations`) where ``keep`` (N,) bool, their points indexed anew."""
    out = {key: value[keep] for key, value in obs.items() if key != "ids"}
    used, out["point"] = np.unique(out["point"], return_inverse=True)
    out["ids"] = obs["ids"][used]
    return out


def solves_poses(keyframes: list[Keyframe], prior_noise: float | None) -> bool:
    """Whether the window solves the rig's poses: a trajectory noise is given (> 0), every keyframe has camera 0's
    metric position, and its cameras share one pose (a shared trigger; COLMAP's rig frame then holds them all)."""
    return bool(prior_noise) and all(kf.prior is not None and shares_pose(kf) for kf in keyframes)


def aligns(keyframes: list[Keyframe], noise: float) -> bool:
    """Whether a window that solves its poses takes camera 0's metric positions (the keyframes' ``prior``) as priors
    (:func:`ocalib.rigba.metric_prior.aligns`, its positions the keyframes' ``poses[0]``)."""
    centres = np.stack([kf.poses[0][:3, 3] for kf in keyframes])
    return metric_aligns(centres, np.stack([kf.prior[:3, 3] for kf in keyframes]), noise)


def shares_pose(kf: Keyframe) -> bool:
    """Whether keyframe ``kf``'s cameras captured their images at one pose of the rig (a shared trigger)."""
    return bool((kf.poses == kf.poses[0]).all())


def _solve(keyframes, points, extrinsics, K, sizes, obs, source, held=frozenset(), prior_noise=None, constant=None):
    """Adjust the window's points (those ``constant`` (P,) bool stay) and rig sensors (robust loss; sensor k sees
    camera ``source[k]``; those in ``held`` stay), the intrinsics held, the rig's poses held or solved
    (:func:`solves_poses`), camera 0's metric positions then priors of ``prior_noise`` metres: ``extrinsics``
    (S, 4, 4) updated in place -> the points (P, 3) of ``obs["ids"]`` and the keyframes' poses (F, C, 4, 4) after
    it."""
    shared = solves_poses(keyframes, prior_noise)
    rec = _reconstruction(keyframes, points, extrinsics, K, sizes, obs, source, shared)
    config = pycolmap.BundleAdjustmentConfig()
    for image_id in rec.images:
        config.add_image(image_id)
    for p in np.flatnonzero(constant) if constant is not None else ():
        config.add_constant_point(int(p) + 1)
    for k in range(len(extrinsics)):
        config.set_constant_cam_intrinsics(k + 1)
    if not shared:
        for frame_id in rec.frames:
            config.set_constant_rig_from_world_pose(frame_id)
    for k in held:
        config.set_constant_sensor_from_rig_pose(_sensor(k))
    options = pycolmap.BundleAdjustmentOptions()
    options.refine_focal_length = options.refine_principal_point = options.refine_extra_params = False
    options.refine_sensor_from_rig = True
    options.print_summary = False
    options.ceres.loss_function_type = pycolmap.LossFunctionType.CAUCHY
    options.ceres.loss_function_scale = LOSS_SCALE_PX
    options.ceres.solver_options.num_threads = 1
    options.ceres.solver_options.max_num_iterations = MAX_ITERATIONS
    if shared:
        _adjust_with_priors(rec, config, options, keyframes, prior_noise)
    else:
        pycolmap.create_default_bundle_adjuster(options, config, rec).solve()
    rig = rec.rig(1)
    for k in range(1, len(extrinsics)):
        extrinsics[k] = np.linalg.inv(to_matrix(rig.sensor_from_rig(_sensor(k))))
    xyz = np.stack([rec.point3D(int(p)).xyz for p in range(1, len(obs["ids"]) + 1)])
    poses = np.stack([kf.poses for kf in keyframes])
    if shared:
        S = len(extrinsics)
        solved = [np.linalg.inv(to_matrix(rec.frame(i * S + 1).rig_from_world)) for i in range(len(keyframes))]
        poses = np.repeat(np.stack(solved)[:, None], poses.shape[1], axis=1)
    return xyz, poses


def _adjust_with_priors(rec, config, options, keyframes, noise: float) -> None:
    """Adjust ``rec`` with camera 0's image of keyframe i (id ``i C + 1``) given the position prior of
    ``keyframes[i].prior``, ``noise`` metres per axis (:func:`ocalib.rigba.metric_prior.adjust_with_position_priors`;
    the window is already in the priors' frame, so COLMAP's alignment is a small move). Where the window does not
    take them (:func:`aligns`: positions on a line) it uses no prior and fixes the gauge at two keyframes' poses."""
    if not aligns(keyframes, noise):
        pycolmap.create_pose_prior_bundle_adjuster(options, pycolmap.PosePriorBundleAdjustmentOptions(), config, [],
                                                   rec).solve()  # fmt: skip
        return
    C = len(rec.cameras)
    images = [i * C + 1 for i in range(len(keyframes))]
    adjust_with_position_priors(rec, options, config, images, np.stack([kf.prior[:3, 3] for kf in keyframes]), noise)


def _reconstruction(keyframes, points, extrinsics, K, sizes, obs, source, shared=False) -> pycolmap.Reconstruction:
    """The window as a COLMAP reconstruction: camera k has id k + 1; keyframe i's image of sensor k has id
    ``i C + k + 1``, in a frame of its own (same id) at the rig's pose when camera ``source[k]`` captured it, or with
    ``shared`` in keyframe i's one frame (id ``i C + 1``, at camera 0's pose); point p (of ``obs["ids"]``) id p + 1.
    Sensor k sees camera ``source[k]``'s keypoints."""
    C = len(extrinsics)
    rec = pycolmap.Reconstruction()
    rig = pycolmap.Rig(rig_id=1)
    for k in range(C):
        height, width = sizes[k]
        rec.add_camera(
            pycolmap.Camera(model="PINHOLE", width=width, height=height, params=pinhole_params(K[k]), camera_id=k + 1)
        )
        if k == 0:
            rig.add_ref_sensor(_sensor(0))
        else:
            rig.add_sensor(_sensor(k), to_rigid(np.linalg.inv(extrinsics[k])))
    rec.add_rig(rig)
    for i, kf in enumerate(keyframes):
        frames = [pycolmap.Frame(frame_id=i * C + k + 1, rig_id=1) for k in range(1 if shared else C)]
        for k in range(C):
            frame = frames[0 if shared else k]
            frame.rig_from_world = to_rigid(np.linalg.inv(kf.poses[source[k]]))
            frame.add_data_id(pycolmap.data_t(_sensor(k), i * C + k + 1))
        for frame in frames:
            rec.add_frame(frame)
        for k in range(C):
            image = pycolmap.Image(
                name=f"c{k}/{kf.frame:06d}",
                keypoints=kf.features[source[k]].keypoints + 0.5,
                camera_id=k + 1,
                image_id=i * C + k + 1,
            )
            image.frame_id = frames[0 if shared else k].frame_id
            rec.add_image(image)
    order = np.argsort(obs["point"], kind="stable")
    starts = np.searchsorted(obs["point"][order], np.arange(len(obs["ids"]) + 1))
    image_ids = obs["frame"] * C + obs["camera"] + 1
    for p, pid in enumerate(obs["ids"]):
        members = order[starts[p] : starts[p + 1]]
        track = pycolmap.Track([pycolmap.TrackElement(int(image_ids[m]), int(obs["keypoint"][m])) for m in members])
        rec.add_point3D(points[int(pid)], track)
    return rec


def _uncertainty(obs, inlier, poses, extrinsics, xyz, K, fitted, prior_noise) -> list[ExtrinsicUncertainty | None]:
    """The extrinsics' uncertainty from the inlying observations (see :mod:`ocalib.rigba.covariance`), the noise
    from those ``fitted`` (N,) bool; ``prior_noise``: the window solved the rig's poses with camera 0's positions
    priors of this noise (metres per axis), or None: it held them (they carry no uncertainty)."""
    C = len(extrinsics)
    used, point = np.unique(obs["point"][inlier], return_inverse=True)
    frames, frame = np.unique(obs["frame"][inlier], return_inverse=True)
    if len(frames) < 3 or len(used) < 10:
        return [None] * (C - 1)
    problem = Observations(
        camera=obs["camera"][inlier],
        frame=frame,
        point=point,
        xy=obs["xy"][inlier] + 0.5,
        rig_from_world=np.linalg.inv(poses[frames]),
        xyz=xyz[used],
        sensor_from_rig=np.linalg.inv(extrinsics),
        pinhole=np.array([pinhole_params(k) for k in K]),
    )
    try:
        return observations_uncertainty(problem, weak_share=0.0, fitted=fitted[inlier], poses_held=prior_noise is None,
                                        position_noise=prior_noise)  # fmt: skip
    except np.linalg.LinAlgError:
        return [None] * (C - 1)


def _sensor(k: int) -> pycolmap.sensor_t:
    """Camera k's sensor (COLMAP camera id k + 1)."""
    return pycolmap.sensor_t(pycolmap.SensorType.CAMERA, k + 1)
