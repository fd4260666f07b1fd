"""COLMAP's camera of a lens against OpenCV's model, the +0.5 pixel shift at the boundary, and the pinhole view of a
distorted reconstruction."""

from __future__ import annotations

import cv2
import numpy as np
import pycolmap
import pytest

from ocalib.data.distortion import Distortion, project
from ocalib.rigba.colmap import colmap_camera, pinhole_equivalent, pinhole_params

K = np.array([[208.0, 0.0, 207.5], [0.0, 204.8, 63.5], [0.0, 0.0, 1.0]])  # the handheld preset at 128x416
SIZE = (128, 416)
CASES = [
    (None, "PINHOLE"),
    (Distortion("opencv", (-0.25, 0.05, 0.001, -0.001, 0.0)), "OPENCV"),
    (Distortion("opencv", (-0.25, 0.05, 0.001, -0.001, -0.004)), "FULL_OPENCV"),
    (Distortion("fisheye", (0.05, -0.01, 0.002, -0.001)), "OPENCV_FISHEYE"),
]


def points(n: int = 500) -> np.ndarray:
    rng = np.random.default_rng(1)
    return np.c_[rng.uniform(-1.4, 1.4, (n, 1)), rng.uniform(-0.5, 0.5, (n, 1)), np.ones(n)] * rng.uniform(
        1, 20, (n, 1)
    )


def opencv_pixels(P: np.ndarray, lens: Distortion | None) -> np.ndarray:
    zero = np.zeros(3)
    if lens is None:
        return cv2.projectPoints(P, zero, zero, K, None)[0][:, 0]
    if lens.model == "fisheye":
        return cv2.fisheye.projectPoints(P[:, None], zero, zero, K, np.array(lens.coeffs))[0][:, 0]
    return cv2.projectPoints(P, zero, zero, K, np.array(lens.coeffs))[0][:, 0]


@pytest.mark.parametrize("lens, model", CASES, ids=[m for _, m in CASES])
def test_colmaps_camera_projects_as_opencv(lens, model):
    camera = colmap_camera(K, SIZE, lens, 3)
    assert (camera.model.name, camera.camera_id, camera.height, camera.width) == (model, 3, *SIZE)
    np.testing.assert_allclose(camera.params[:4], pinhole_params(K))
    P = points()
    np.testing.assert_allclose(camera.img_from_cam(P) - 0.5, opencv_pixels(P, lens), atol=1e-6)


def one_image(camera: pycolmap.Camera, keypoints: np.ndarray) -> pycolmap.Reconstruction:
    """A reconstruction of one camera (id 1) in a one-sensor rig and one image of it with ``keypoints`` (COLMAP's)."""
    rec = pycolmap.Reconstruction()
    rec.add_camera(camera)
    sensor = pycolmap.sensor_t(pycolmap.SensorType.CAMERA, 1)
    rig = pycolmap.Rig(rig_id=1)
    rig.add_ref_sensor(sensor)
    rec.add_rig(rig)
    frame = pycolmap.Frame(frame_id=1, rig_id=1)
    frame.add_data_id(pycolmap.data_t(sensor, 1))
    rec.add_frame(frame)
    image = pycolmap.Image(name="a", keypoints=keypoints, camera_id=1, image_id=1)
    image.frame_id = 1
    rec.add_image(image)
    return rec


def test_the_pinhole_equivalent_moves_keypoints_to_their_rays_pinhole_pixels():
    lens = CASES[3][0]
    P = points(20)
    rec = one_image(colmap_camera(K, SIZE, lens, 1), project(P, K, lens) + 0.5)
    out = pinhole_equivalent(rec)
    assert out.camera(1).model.name == "PINHOLE" and len(out.camera(1).params) == 4
    xy = np.array([p.xy for p in out.image(1).points2D])
    np.testing.assert_allclose(xy - 0.5, project(P, K, None), atol=1e-6)
    assert rec.camera(1).model.name == "OPENCV_FISHEYE"  # the original is left alone
    pinhole = one_image(colmap_camera(K, SIZE, None, 1), project(P, K, None) + 0.5)
    assert pinhole_equivalent(pinhole) is pinhole
