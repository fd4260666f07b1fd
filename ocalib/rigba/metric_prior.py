"""Camera 0's metric trajectory inside the rig bundle adjustment: its positions as weighted priors (COLMAP's
pose-prior bundle adjuster), so that the rig's path, its points and every camera's extrinsic are solved in metres
together, instead of a reconstruction scaled to metres after the fact.

COLMAP aligns the reconstruction to the priors (a Sim(3) by RANSAC) and adjusts the points, the rig's poses and every
``sensor_from_rig`` with each prior's squared Mahalanobis distance beside the reprojection errors, weighed by the
trajectory's noise (metres, per axis) as its user states it.

Convention: ``metric`` (T, 4, 4) camera 0's camera-to-world poses in metres, indexed by frame; the reconstruction's
images named as :mod:`ocalib.rigba.workspace` names them.
"""

from __future__ import annotations

import numpy as np
import pycolmap

MIN_PRIORS = 3  # registered camera-0 frames needed


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
    few camera-0 frames registered."""
    images = [i for i, image in rec.images.items() if image.camera_id == camera_id and image.has_pose]
    if len(images) < MIN_PRIORS:
        return False
    positions = metric[[frame_of[i] for i in images], :3, 3]
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
    return True
