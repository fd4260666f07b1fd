"""Camera 0's metric trajectory inside the rig bundle adjustment, so that the rig's path, its points and every
camera's extrinsic are solved in metres together, instead of a reconstruction scaled to metres after the fact; two
ways:

- :func:`adjust_with_metric_prior`: its positions as weighted priors (COLMAP's pose-prior bundle adjuster, which aligns
  the reconstruction to them by a Sim(3) RANSAC and adjusts points, rig poses and every ``sensor_from_rig`` with each
  prior's squared Mahalanobis distance beside the reprojection errors, weighed by the noise its user states; the
  positions moved off the origin meanwhile, :func:`off_origin`);
- :func:`adjust_with_metric_held`: its poses held fixed, only the points and the extrinsics adjusted (the way of
  odometry-based rig calibration, e.g. CamOdoCal): the lever arm is then measured against the trajectory directly.

Convention: ``metric`` (T, 4, 4) camera 0's camera-to-world poses in metres, indexed by frame; the reconstruction's
images named as :mod:`ocalib.rigba.workspace` names them; the rig's frame is camera 0's.
"""

from __future__ import annotations

import numpy as np
import pycolmap

from ocalib.geometry.alignment import umeyama
from ocalib.rigba.colmap import camera_to_world, to_rigid
from ocalib.rigba.workspace import camera_and_frame

MIN_PRIORS = 3  # registered camera-0 frames needed
ALIGNMENT_SIGMAS = 3.0  # priors are taken where a similarity aligns them within this many sigmas
MAX_ERROR_PX = 4.0  # an observation reprojected farther than this with the trajectory held is dropped
MIN_ANGLE_DEG = 1.5  # and a point triangulated over less than this (COLMAP's mapper's default)


def adjust_with_metric_prior(
    rec: pycolmap.Reconstruction,
    camera_id: int,
    frame_of: dict[int, int],
    metric: np.ndarray,
    noise: float,
    threads: int = -1,
) -> bool:
    """Adjust ``rec`` in place with camera 0's positions from ``metric`` (T, 4, 4) as priors on its images of
    ``camera_id`` (``frame_of``: image id -> frame), ``noise`` metres per axis. False (``rec`` unchanged) where too
    few camera-0 frames registered or no similarity aligns them to the positions within three times ``noise``."""
    images = [i for i, image in rec.images.items() if image.camera_id == camera_id and image.has_pose]
    if len(images) < MIN_PRIORS:
        return False
    positions = metric[[frame_of[i] for i in images], :3, 3]
    centres = np.stack([rec.images[i].projection_center() for i in images])
    if not aligns(centres, positions, noise):
        return False
    adjust_with_position_priors(rec, _options(threads), _config(rec), images, positions, noise)
    return True


def adjust_with_position_priors(
    rec: pycolmap.Reconstruction,
    options: pycolmap.BundleAdjustmentOptions,
    config: pycolmap.BundleAdjustmentConfig,
    images: list[int],
    positions: np.ndarray,
    noise: float,
) -> None:
    """Adjust ``rec`` in place on COLMAP's pose-prior adjuster, image ``images[i]`` with the position prior
    ``positions[i]`` ((N, 3) metres, ``noise`` per axis). COLMAP first aligns ``rec`` to them by a seeded Sim(3)
    RANSAC (:func:`aligns`; where that fails it uses no prior and fixes the gauge at two images); the world is moved
    off the origin meanwhile (:func:`off_origin`) and back."""
    shift = off_origin(positions)
    rec.transform(translation(shift))
    priors = [
        pycolmap.PosePrior(
            corr_data_id=rec.images[i].data_id,
            position=p,
            position_covariance=np.eye(3) * noise**2,
            coordinate_system=pycolmap.PosePriorCoordinateSystem.CARTESIAN,
        )
        for i, p in zip(images, positions + shift)
    ]
    prior_options = pycolmap.PosePriorBundleAdjustmentOptions()
    prior_options.alignment_ransac = _alignment(noise)
    pycolmap.create_pose_prior_bundle_adjuster(options, prior_options, config, priors, rec).solve()
    rec.transform(translation(-shift))


def aligns(centres: np.ndarray, positions: np.ndarray, noise: float) -> bool:
    """Whether COLMAP's pose-prior adjuster takes ``positions`` (N, 3) as priors of the images at ``centres`` (N, 3):
    its seeded Sim(3) RANSAC aligns them within ``ALIGNMENT_SIGMAS`` times ``noise``, both moved off the origin as
    :func:`adjust_with_position_priors` moves them. It does not where they lie on a line, or farther off."""
    shift = off_origin(positions)
    return pycolmap.estimate_sim3d_robust(centres + shift, positions + shift, _alignment(noise)) is not None


def _alignment(noise: float) -> pycolmap.RANSACOptions:
    """The seeded RANSAC options of the Sim(3) alignment to position priors of ``noise`` metres."""
    options = pycolmap.PosePriorBundleAdjustmentOptions().alignment_ransac
    options.max_error, options.random_seed = ALIGNMENT_SIGMAS * noise, 0
    return options


def off_origin(positions: np.ndarray) -> np.ndarray:
    """A translation (3,) that takes ``positions`` (N >= 3, 3) off every plane through the origin: their centroid to
    the origin, then their extent (plus a metre) along the normal of their best plane. COLMAP's Sim(3) estimate
    rejects a sample whose *uncentred* positions have rank under 3, which every sample of positions in a plane
    through the origin has: a drive on level ground, its trajectory re-referenced to its first frame."""
    centre = positions.mean(0)
    _, s, vt = np.linalg.svd(positions - centre, full_matrices=False)
    return vt[-1] * (s[0] / np.sqrt(len(positions)) + 1.0) - centre


def translation(shift: np.ndarray) -> pycolmap.Sim3d:
    """The similarity that translates the world by ``shift`` (3,)."""
    return pycolmap.Sim3d(1.0, pycolmap.Rotation3d(), shift)


def adjust_with_metric_held(
    rec: pycolmap.Reconstruction, frame_of: dict[int, int], metric: np.ndarray, threads: int = -1
) -> pycolmap.Reconstruction | None:
    """A copy of ``rec`` adjusted with every rig frame held at camera 0's pose from ``metric`` (T, 4, 4; the rig's
    frame is camera 0's): moved onto ``metric`` by a Sim(3) fit of camera 0's positions, then only the points and
    the extrinsics adjusted (CamOdoCal's way with odometry), robustly, the observations then farther than
    ``MAX_ERROR_PX`` dropped, and adjusted again. ``frame_of``: image id -> frame. None where too few camera-0
    frames registered."""
    zero = [i for i, image in rec.images.items() if image.has_pose and camera_and_frame(image.name)[0] == 0]
    if len(zero) < MIN_PRIORS:
        return None
    rec = pycolmap.Reconstruction(rec)
    centres = np.stack([camera_to_world(rec.images[i])[:3, 3] for i in zero])
    s, R, t = umeyama(centres, metric[[frame_of[i] for i in zero], :3, 3])
    rec.transform(pycolmap.Sim3d(s, pycolmap.Rotation3d(R), t))
    config = _config(rec)
    for frame_id, frame in rec.frames.items():
        if frame.has_pose:
            frame.rig_from_world = to_rigid(np.linalg.inv(metric[frame_of[next(iter(frame.image_ids)).id]]))
            config.set_constant_rig_from_world_pose(frame_id)
    options = _options(threads)
    for loss in (pycolmap.LossFunctionType.CAUCHY, pycolmap.LossFunctionType.TRIVIAL):
        options.ceres.loss_function_type = loss
        pycolmap.create_default_bundle_adjuster(options, config, rec).solve()
        pycolmap.ObservationManager(rec).filter_all_points3D(MAX_ERROR_PX, MIN_ANGLE_DEG)
    rec.update_point_3d_errors()
    return rec


def _config(rec: pycolmap.Reconstruction) -> pycolmap.BundleAdjustmentConfig:
    """Every registered image of ``rec``, the intrinsics held."""
    config = pycolmap.BundleAdjustmentConfig()
    for image_id in rec.reg_image_ids():
        config.add_image(image_id)
    for cid in rec.cameras:
        config.set_constant_cam_intrinsics(cid)
    return config


def _options(threads: int) -> pycolmap.BundleAdjustmentOptions:
    """The intrinsics held, every ``sensor_from_rig`` refined, quiet, on ``threads`` threads."""
    options = pycolmap.BundleAdjustmentOptions()
    options.refine_focal_length = options.refine_principal_point = options.refine_extra_params = False
    options.refine_sensor_from_rig = True
    options.print_summary = False
    options.ceres.solver_options.num_threads = threads
    return options
