"""A distorted render against OpenCV's model: its pixels' depths are where OpenCV's rays meet the ground, and
undistorted by OpenCV it is the pinhole render of the same pose; the lens goes into rig.yaml; a bad lens in a synth
config is one line and exit code 2."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import yaml

from ocalib.cli import main
from ocalib.data.distortion import Distortion
from ocalib.data.rig import read_rig_yaml
from ocalib.synth import config_from_dict, load_config, preset
from ocalib.synth.render import WorldTensors, render_view
from ocalib.synth.sequence import camera_poses, world_for

H, W = 64, 208
LENSES = [Distortion("fisheye", (0.05, -0.01, 0.002, -0.001)), Distortion("opencv", (-0.25, 0.05, 0.001, -0.001, 0.0))]


@pytest.fixture(scope="module")
def scene():
    """The handheld preset's world, camera 0's pose at frame 0, its K at 64x208 and its pinhole render."""
    cfg = preset("handheld").with_overrides(frames=2, height=H, width=W, seed=1001)
    poses = camera_poses(cfg)
    world = WorldTensors.from_world(world_for(cfg, poses))
    K = cfg.cameras[0].K(H, W)
    return world, poses[0, 0], K, render_view(world, K, poses[0, 0], H, W, 1)


def opencv_rays(K: np.ndarray, lens: Distortion) -> np.ndarray:
    """(H, W, 3) camera-frame rays (z = 1) of the pixel centres by OpenCV's own undistortion (iterated to 1e-12)."""
    v, u = np.mgrid[0:H, 0:W]
    pixels = np.c_[u.ravel(), v.ravel()].astype(np.float64)[:, None]
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    D = np.array(lens.coeffs)
    if lens.model == "fisheye":
        xy = cv2.fisheye.undistortPoints(pixels, K, D, criteria=criteria)
    else:
        xy = cv2.undistortPointsIter(pixels, K, D, None, None, criteria)
    return np.c_[xy[:, 0], np.ones(H * W)].reshape(H, W, 3)


@pytest.mark.parametrize("lens", LENSES, ids=lambda d: d.model)
def test_a_distorted_render_is_opencvs_lens(scene, lens):
    world, pose, K, (_, pinhole_depth) = scene
    image, depth = render_view(world, K, pose, H, W, 1, lens)
    depth = depth.numpy().astype(np.float64)
    # Ground pixels: the depth is where OpenCV's ray of the pixel centre meets the plane z = 0.
    rays = opencv_rays(K, lens) @ pose[:3, :3].T
    ground = np.where(rays[..., 2] < 0, -pose[2, 3] / np.minimum(rays[..., 2], -1e-12), np.inf)
    on_ground = np.abs(depth - ground) < 1e-4 * ground
    assert on_ground.mean() > 0.1, on_ground.mean()
    pinhole_rays = np.c_[(np.mgrid[0:H, 0:W][::-1].reshape(2, -1).T - K[:2, 2]) / K[[0, 1], [0, 1]], np.ones(H * W)]
    pinhole_ground = -pose[2, 3] / np.minimum((pinhole_rays @ pose[:3, :3].T)[:, 2], -1e-12)
    assert (np.abs(depth.ravel() - pinhole_ground) < 1e-4 * np.abs(pinhole_ground)).mean() < 0.5 * on_ground.mean()
    # Undistorted by OpenCV's maps, the render is the pinhole one (up to the nearest pixel's depth step).
    D = np.array(lens.coeffs)
    if lens.model == "fisheye":
        maps = cv2.fisheye.initUndistortRectifyMap(K, D, np.eye(3), K, (W, H), cv2.CV_32FC1)
    else:
        maps = cv2.initUndistortRectifyMap(K, D, None, K, (W, H), cv2.CV_32FC1)
    undistorted = cv2.remap(depth.astype(np.float32), *maps, cv2.INTER_NEAREST)
    truth = pinhole_depth.numpy()
    seen = (truth > 0) & (undistorted > 0)
    relative = np.abs(undistorted[seen] - truth[seen]) / truth[seen]
    assert np.median(relative) < 0.01 and np.mean(relative < 0.05) > 0.85, (
        np.median(relative),
        np.mean(relative < 0.05),
    )


def test_the_lens_is_written_into_rig_yaml_and_a_bad_one_is_one_line(tmp_path, capsys):
    config = {
        "name": "lens",
        "frames": 2,
        "height": 32,
        "width": 104,
        "seed": 1001,
        "trajectory": {"kind": "handheld"},
        "cameras": [{"name": "cam0", "distortion": LENSES[0].as_dict()}, {"name": "cam1", "position": [0.1, 0, 0]}],
    }
    (tmp_path / "lens.yaml").write_text(yaml.safe_dump(config))
    assert (
        main(["synth", "--config", str(tmp_path / "lens.yaml"), "--out", str(tmp_path / "seq"), "--workers", "1"]) == 0
    )
    assert [c.distortion for c in read_rig_yaml(tmp_path / "seq" / "rig.yaml").cameras] == [LENSES[0], None]
    config["cameras"][1]["distortion"] = {"model": "opencv", "coeffs": [-0.9, 0, 0, 0, 0]}
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump(config))
    capsys.readouterr()
    assert (
        main(["synth", "--config", str(tmp_path / "bad.yaml"), "--out", str(tmp_path / "bad"), "--workers", "1"]) == 2
    )
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("ocalib synth: error: "), lines
    assert f"{tmp_path / 'bad.yaml'}: camera cam1: distortion" in lines[0] and "folds back" in lines[0], lines
    cfg = load_config(tmp_path / "lens.yaml")
    assert config_from_dict(yaml.safe_load(yaml.safe_dump(cfg.to_dict()))).cameras[0].distortion == LENSES[0]
