"""Lens distortion: ocalib's models against OpenCV's, undistortion, the undistorted view the front ends read, and
rig.yaml's distortion entries."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import yaml
from data_fixtures import write_rig

from ocalib.data import open_sequence
from ocalib.data.distortion import (
    Distortion,
    distort,
    project,
    undistort,
    undistort_image,
    undistort_maps,
    undistort_pixels,
)
from ocalib.data.image_io import read_image
from ocalib.data.rig import CameraSpec, RigSpec, read_rig_yaml, write_rig_yaml
from ocalib.errors import InputError

K = np.array([[104.0, 0.0, 103.5], [0.0, 102.4, 31.5], [0.0, 0.0, 1.0]])  # the handheld preset at 64x208
LENSES = [
    Distortion("opencv", (-0.25, 0.05, 0.001, -0.001, -0.004)),
    Distortion("opencv", (0.1, -0.02, -0.002, 0.003, 0.0)),
    Distortion("fisheye", (0.05, -0.01, 0.002, -0.001)),
]


def points(n: int = 500, seed: int = 0) -> np.ndarray:
    """Camera-frame points (n, 3) seen within about 55 deg of the axis, 1-20 m away."""
    rng = np.random.default_rng(seed)
    return np.c_[rng.uniform(-1.4, 1.4, (n, 1)), rng.uniform(-0.5, 0.5, (n, 1)), np.ones(n)] * rng.uniform(
        1, 20, (n, 1)
    )


def opencv_project(P: np.ndarray, distortion: Distortion) -> np.ndarray:
    D, zero = np.array(distortion.coeffs), np.zeros(3)
    if distortion.model == "fisheye":
        return cv2.fisheye.projectPoints(P[:, None], zero, zero, K, D)[0][:, 0]
    return cv2.projectPoints(P, zero, zero, K, D)[0][:, 0]


@pytest.mark.parametrize("lens", LENSES, ids=lambda d: d.model)
def test_projection_is_opencvs(lens):
    P = points()
    np.testing.assert_allclose(project(P, K, lens), opencv_project(P, lens), atol=1e-6)


@pytest.mark.parametrize("lens", LENSES, ids=lambda d: d.model)
def test_undistort_inverts_distort(lens):
    xy = points()[:, :2] / points()[:, 2:]
    np.testing.assert_allclose(undistort(distort(xy, lens), lens), xy, atol=1e-9)
    P = points()
    np.testing.assert_allclose(undistort_pixels(project(P, K, lens), K, lens), project(P, K, None), atol=1e-6)


def test_a_lens_that_folds_back_has_no_inverse_there():
    strong = Distortion("opencv", (-0.6, 0.0, 0.0, 0.0, 0.0))  # r (1 - 0.6 r^2) peaks at r_d = 0.54
    out = undistort(np.array([[0.3, 0.0], [0.6, 0.0]]), strong)
    assert np.isfinite(out[0]).all() and np.isnan(out[1]).all()


@pytest.mark.parametrize("lens", LENSES, ids=lambda d: d.model)
def test_the_undistortion_maps_follow_the_model_and_are_cached(lens):
    """Pinhole pixel p of the undistorted image samples the distorted image where the lens sends p's ray."""
    map_x, map_y = undistort_maps(K, (64, 208), lens)
    v, u = np.mgrid[0:64:7, 0:208:9]
    rays = np.c_[u.ravel(), v.ravel(), np.ones(u.size)] @ np.linalg.inv(K).T
    expected = project(rays, K, lens)
    np.testing.assert_allclose(np.c_[map_x[v, u].ravel(), map_y[v, u].ravel()], expected, atol=2e-3)
    assert undistort_maps(K.copy(), (64, 208), lens)[0] is map_x  # once per camera


def test_the_front_ends_read_the_undistorted_view(tmp_path):
    """Camera.read is the one loading point: the undistorted image of a camera with a lens, the file otherwise; its
    grey (read_grey) the same view."""
    write_rig(tmp_path, n=2)
    text = yaml.safe_load((tmp_path / "rig.yaml").read_text())
    text["cameras"][1]["distortion"] = LENSES[2].as_dict()
    (tmp_path / "rig.yaml").write_text(yaml.safe_dump(text))
    seq = open_sequence(tmp_path)
    pinhole, lens = seq.cameras
    assert pinhole.distortion is None and lens.distortion == LENSES[2]
    assert (pinhole.read(1) == read_image(pinhole.images[1])).all()
    raw = cv2.cvtColor(cv2.imread(str(lens.images[1])), cv2.COLOR_BGR2RGB)
    expected = undistort_image(raw, lens.K, lens.distortion).astype(np.float32) / 255
    np.testing.assert_array_equal(lens.read(1).permute(1, 2, 0).numpy(), expected)
    assert lens.read(1, (12, 40)).shape == (3, 12, 40)
    for camera in (pinhole, lens):  # the OpenCV front end's grey: the same view
        rgb = (camera.read(1) * 255).round().byte().permute(1, 2, 0).numpy()
        np.testing.assert_array_equal(camera.read_grey(1), cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY))


def test_rig_yaml_round_trip(tmp_path):
    cams = [CameraSpec("a", 208, 64, K), CameraSpec("b", 208, 64, K, distortion=LENSES[0])]
    write_rig_yaml(tmp_path / "rig.yaml", RigSpec(cams))
    assert [c.distortion for c in read_rig_yaml(tmp_path / "rig.yaml").cameras] == [None, LENSES[0]]


@pytest.mark.parametrize("entry, message", [
    ({"model": "kannala", "coeffs": [0, 0, 0, 0]}, "unknown model 'kannala' (models: opencv, fisheye)"),
    ({"model": "opencv", "coeffs": [0.1, 0.0, 0.0, 0.0]}, "model opencv needs 5 coeffs [k1, k2, p1, p2, k3]"),
    ({"model": "fisheye", "coeffs": [0.1, 0.0, 0.0, 0.0, 0.0]}, "model fisheye needs 4 coeffs"),
    ({"model": "fisheye", "coeffs": [0.1, "x", 0.0, 0.0]}, "coeffs must be finite numbers"),
    ({"model": "fisheye", "coeffs": [0.1, float("nan"), 0.0, 0.0]}, "coeffs must be finite numbers"),
    ({"model": "fisheye", "coeffs": [0.1, True, 0.0, 0.0]}, "coeffs must be finite numbers"),
    ({"model": "fisheye"}, "distortion must be a mapping with exactly model and coeffs"),
    ("fisheye", "distortion must be a mapping with exactly model and coeffs"),
])  # fmt: skip
def test_a_bad_distortion_entry_names_the_file_and_camera(tmp_path, entry, message):
    cams = [{"name": "a", "width": 208, "height": 64, "K": K.tolist()}]
    cams.append(cams[0] | {"name": "side", "distortion": entry})
    (tmp_path / "rig.yaml").write_text(yaml.safe_dump({"cameras": cams}))
    with pytest.raises(InputError) as err:
        read_rig_yaml(tmp_path / "rig.yaml")
    assert f"{tmp_path / 'rig.yaml'}: cameras[1] (side): distortion" in str(err.value)
    assert message in str(err.value)
