"""Camera 0's metric trajectory inside the rig bundle adjustment: its positions as weighted priors (COLMAP's
pose-prior bundle adjuster), so that the rig's path, its points and every camera's extrinsic are solved in metres
together, instead of a reconstruction scaled to metres after the fact.

COLMAP aligns the reconstruction to the priors (a Sim(3) by RANSAC) and adjusts the points, the rig's poses and every
``sensor_from_rig`` with each prior's squared Mahalanobis distance beside the reprojection errors. The priors' noise
(metres, per axis) is the trajectory's as stated or, by default, estimated: the RMS per axis of the Sim(3) fit of the
reconstruction's camera-0 positions to the trajectory, which bounds the two disagreeing, floored at
:data:`MIN_NOISE_M`.

Convention: ``metric`` (T, 4, 4) camera 0's camera-to-world poses in metres, indexed by frame; the reconstruction's
images named as :mod:`ocalib.rigba.workspace` names them.
"""

from __future__ import annotations

import numpy as np
import pycolmap

from ocalib.errors import InputError
from ocalib.eval.alignment import umeyama

MIN_NOISE_M = 1e-3  # the estimated noise is not taken below a millimetre
MIN_PRIORS = 3  # registered camera-0 frames needed


def adjust_with_metric_prior(
    rec: pycolmap.Reconstruction,
    camera_id: int,
    frame_of: dict[int, int],
    metric: np.ndarray,
    noise: float | None = None,
    threads: int = -1,
) -> float | None:
    """Adjust ``rec`` in place with camera 0's positions from ``metric`` (T, 4, 4) as priors on its images of
    ``camera_id`` (``frame_of``: image id -> frame); ``noise`` metres per axis (None: estimated). Returns the noise
    used; None where too few camera-0 frames registered (``rec`` unchanged)."""
    images = [i for i, image in rec.images.items() if image.camera_id == camera_id and image.has_pose]
    if len(images) < MIN_PRIORS:
        return None
    positions = metric[[frame_of[i] for i in images], :3, 3]
    if noise is None:
        centres = np.stack([rec.images[i].projection_center() for i in images])
        try:
            scale, R, t = umeyama(centres, positions)
        except InputError:  # camera 0 did not move in the reconstruction
            return None
        residual = positions - (scale * centres @ R.T + t)
        noise = max(float(np.sqrt(np.mean(residual**2))), MIN_NOISE_M)
    priors = [
        pycolmap.PosePrior(
            corr_data_id=rec.images[i].data_id,
            position=p,
            position_covariance=np.eye(3) * noise**2,
            coordinate_system=pycolmap.PosePriorCoordinateSystem.CARTESIAN,
        )
        for i, p in zip(images, positions)
    ]
    config = pycolmap.BundleAdjustmentConfig()
    for image_id in rec.reg_image_ids():
        config.add_image(image_id)
    for cid in rec.cameras:
        config.set_constant_cam_intrinsics(cid)
    options = pycolmap.BundleAdjustmentOptions()
    options.refine_focal_length = options.refine_principal_point = options.refine_extra_params = False
    options.refine_sensor_from_rig = True
    options.print_summary = False
    options.ceres.solver_options.num_threads = threads
    prior_options = pycolmap.PosePriorBundleAdjustmentOptions()
    prior_options.alignment_ransac.max_error = 3 * noise  # metres: a camera-0 position this far off is an outlier
    pycolmap.create_pose_prior_bundle_adjuster(options, prior_options, config, priors, rec).solve()
    return noise
