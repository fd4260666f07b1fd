"""The boundary to COLMAP: intrinsics, poses and rigs converted once, here (a camera's model and parameters by
:func:`ocalib.io.export.colmap_intrinsics`, which the COLMAP export shares).

Convention: ocalib's K has integer pixel centres (kornia's and OpenCV's); COLMAP's camera models put them at +0.5,
so their principal point is ``K[:2, 2] + 0.5`` (the lens's coefficients act on normalised coordinates, unchanged). COLMAP stores world-to-camera transforms (``cam_from_world``) and each
sensor's ``sensor_from_rig``; with camera 0 as the rig frame, ``T_cam0_camk = inverse(sensor_from_rig_k)``
(``p_cam0 = R p_camk + t``) and camera 0's camera-to-world pose is ``inverse(cam_from_world)``.
"""

from __future__ import annotations

import signal

import numpy as np
import pycolmap

from ocalib.data.distortion import Distortion
from ocalib.io.export import colmap_intrinsics

QUIET = 2  # COLMAP's log level while ocalib runs it: errors only (its INFO log is thousands of lines a run)
pycolmap.logging.minloglevel = QUIET
# Importing pycolmap installs glog's crash handler on SIGTERM too, so every worker process a pool or a DataLoader
# ends with SIGTERM printed a stack trace; SIGTERM gets Python's handler back (the crash signals keep glog's).
try:
    signal.signal(signal.SIGTERM, signal.getsignal(signal.SIGTERM) or signal.SIG_DFL)
except ValueError:  # imported outside the main thread, where signals cannot be set
    pass


def pinhole_params(K: np.ndarray) -> list[float]:
    """COLMAP PINHOLE parameters ``fx, fy, cx, cy`` of ocalib's K (3, 3) (pixel centres shifted by +0.5)."""
    return colmap_intrinsics(K, None)[1]


def colmap_camera(
    K: np.ndarray, size: tuple[int, int], distortion: Distortion | None, camera_id: int
) -> pycolmap.Camera:
    """COLMAP's camera of ocalib's K (3, 3), image size (H, W) and lens (:mod:`ocalib.data.distortion`), its model
    and parameters :func:`~ocalib.io.export.colmap_intrinsics`'s (PINHOLE, OPENCV, FULL_OPENCV or OPENCV_FISHEYE)."""
    model, params = colmap_intrinsics(K, distortion)
    height, width = size
    return pycolmap.Camera(model=model, width=int(width), height=int(height), params=params, camera_id=camera_id)


def pinhole_equivalent(rec: pycolmap.Reconstruction) -> pycolmap.Reconstruction:
    """A copy of ``rec`` whose cameras are PINHOLE (the same fx, fy, cx, cy) and whose keypoints are moved to the
    pinhole pixels of their rays: what a pinhole-only consumer (the covariance) reads of a distorted one; ``rec``
    itself where every camera is PINHOLE."""
    if all(camera.model == pycolmap.CameraModelId.PINHOLE for camera in rec.cameras.values()):
        return rec
    out = pycolmap.Reconstruction(rec)
    lenses = {cid: camera for cid, camera in out.cameras.items() if camera.model != pycolmap.CameraModelId.PINHOLE}
    for image in out.images.values():
        camera = lenses.get(image.camera_id)
        if camera is None or not len(image.points2D):
            continue
        xy = camera.cam_from_img(np.array([p.xy for p in image.points2D]))
        pixels = xy * camera.params[:2] + camera.params[2:4]
        for point, pixel in zip(image.points2D, pixels):
            point.xy = pixel
    for camera in lenses.values():
        camera.model, camera.params = pycolmap.CameraModelId.PINHOLE, camera.params[:4]
    return out


def intrinsics_matrix(params) -> np.ndarray:
    """ocalib's K (3, 3) of COLMAP PINHOLE parameters (the inverse of :func:`pinhole_params`)."""
    fx, fy, cx, cy = (float(v) for v in params)
    return np.array([[fx, 0.0, cx - 0.5], [0.0, fy, cy - 0.5], [0.0, 0.0, 1.0]])


def to_rigid(T: np.ndarray) -> pycolmap.Rigid3d:
    """A 4x4 rigid transform as COLMAP's Rigid3d (same direction: ``Rigid3d * p = R p + t``)."""
    T = np.asarray(T, dtype=np.float64)
    return pycolmap.Rigid3d(pycolmap.Rotation3d(T[:3, :3]), T[:3, 3])


def to_matrix(rigid: pycolmap.Rigid3d) -> np.ndarray:
    """COLMAP's Rigid3d as a 4x4 float64 matrix (same direction)."""
    T = np.eye(4)
    T[:3, :] = rigid.matrix()
    return T


def camera_to_world(image: pycolmap.Image) -> np.ndarray:
    """A registered image's camera-to-world pose (4, 4)."""
    return np.linalg.inv(to_matrix(image.cam_from_world()))
