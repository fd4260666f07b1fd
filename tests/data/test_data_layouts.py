"""Every layout opens through open_sequence with its cameras, K, sizes, times, poses and extrinsics."""

import numpy as np
import pytest
from data_fixtures import (
    BASELINES,
    H,
    K,
    W,
    trajectory,
    write_folder,
    write_kitti_odometry,
    write_kitti_raw,
    write_rig,
    write_sfmlearner,
)

from ocalib.data import detect_layout, find_sequences, open_sequence


def test_rig_layout(tmp_path):
    truth = write_rig(tmp_path / "rig", n=5)
    seq = open_sequence(tmp_path / "rig")
    assert seq.layout == "rig" and seq.names == ["cam0", "cam1"] and len(seq) == 5
    np.testing.assert_allclose(seq.times, 0.1 * np.arange(5), atol=1e-9)
    cam1 = seq.camera("cam1")
    assert cam1.size == (H, W) and len(cam1.depth) == 5
    np.testing.assert_allclose(cam1.K, K)
    np.testing.assert_allclose(cam1.T_cam0_cam, truth["extrinsics"][1], atol=1e-12)
    np.testing.assert_allclose(cam1.poses, seq.camera("cam0").poses @ cam1.T_cam0_cam, atol=1e-8)


def test_rig_camera_selection_rereferences_extrinsics(tmp_path):
    truth = write_rig(tmp_path / "rig", n=3)
    assert open_sequence(tmp_path / "rig", intrinsics="unused.yaml").layout == "rig"
    seq = open_sequence(tmp_path / "rig", cameras=["cam1", "cam0"])
    assert seq.names == ["cam1", "cam0"]
    np.testing.assert_allclose(seq.cameras[0].T_cam0_cam, np.eye(4), atol=1e-12)
    np.testing.assert_allclose(seq.cameras[1].T_cam0_cam, np.linalg.inv(truth["extrinsics"][1]), atol=1e-12)


@pytest.mark.parametrize("calib_beside", [True, False])
def test_kitti_raw(tmp_path, calib_beside):
    truth = write_kitti_raw(tmp_path, n=4, calib_beside=calib_beside)
    seq = open_sequence(truth["drive"])
    assert seq.layout == "kitti_raw" and seq.names == ["image_00", "image_01", "image_02", "image_03"]
    assert len(seq) == 4 and all(c.size == (H, W) for c in seq.cameras)
    np.testing.assert_allclose(np.diff(seq.times), 0.1036, atol=1e-6)
    for i, cam in enumerate(seq.cameras):
        np.testing.assert_allclose(cam.K, K, atol=1e-9)
        np.testing.assert_allclose(cam.T_cam0_cam[:3, 3], [BASELINES[i], 0, 0], atol=1e-9)  # camera 1: 0.54 m right
        relative = np.linalg.inv(cam.poses[0]) @ cam.poses
        expected = np.linalg.inv(cam.T_cam0_cam) @ np.linalg.inv(truth["poses0"][0]) @ truth["poses0"] @ cam.T_cam0_cam
        np.testing.assert_allclose(relative, expected, atol=1e-6)


def test_kitti_raw_colour_cameras_only(tmp_path):
    truth = write_kitti_raw(tmp_path, n=3)
    seq = open_sequence(truth["drive"], cameras=["image_02", "image_03"])
    np.testing.assert_allclose(seq.cameras[1].T_cam0_cam[:3, 3], [BASELINES[3] - BASELINES[2], 0, 0], atol=1e-9)
    np.testing.assert_allclose(seq.cameras[1].poses, seq.cameras[0].poses @ seq.cameras[1].T_cam0_cam, atol=1e-8)


def test_kitti_odometry(tmp_path):
    folder = write_kitti_odometry(tmp_path, n=4)
    seq = open_sequence(folder)
    assert seq.layout == "kitti_odometry" and seq.names == ["image_0", "image_1", "image_2", "image_3"]
    np.testing.assert_allclose(seq.times, 0.1 * np.arange(4), atol=1e-9)
    np.testing.assert_allclose(seq.cameras[0].poses, trajectory(4), atol=1e-8)
    for i, cam in enumerate(seq.cameras):
        assert cam.size == (H, W)
        np.testing.assert_allclose(cam.K, K, atol=1e-9)
        np.testing.assert_allclose(cam.T_cam0_cam[:3, 3], [BASELINES[i], 0, 0], atol=1e-9)
        np.testing.assert_allclose(cam.poses, trajectory(4) @ cam.T_cam0_cam, atol=1e-8)
    assert find_sequences(tmp_path / "dataset") == [folder]


def test_kitti_odometry_without_ground_truth(tmp_path):
    seq = open_sequence(write_kitti_odometry(tmp_path, n=3, seq="11", with_poses=False))
    assert all(c.poses is None for c in seq.cameras) and seq.cameras[2].T_cam0_cam is not None


def test_sfmlearner_root_and_splits(tmp_path):
    root = write_sfmlearner(tmp_path / "prepared")
    train, val = find_sequences(root / "train.txt"), find_sequences(root / "val.txt")
    assert [p.name for p in train] == ["s1_02", "s2_02"] and [p.name for p in val] == ["s3_03"]
    assert len(find_sequences(root)) == 3
    seq = open_sequence(train[0])
    assert seq.layout == "sfmlearner" and seq.names == ["cam0"] and len(seq) == 4
    np.testing.assert_allclose(seq.cameras[0].K, K)


@pytest.mark.parametrize(
    "name,text",
    [
        ("intrinsics.yaml", None),
        ("intrinsics.yml", "K: [[50, 0, 39.5], [0, 50, 11.5], [0, 0, 1]]\n"),
        ("intrinsics.yaml", "fx: 100\nfy: 100\ncx: 79.5\ncy: 23.5\nwidth: 160\nheight: 48\n"),  # rescaled to 80x24
        ("K.txt", None),
    ],
)
def test_plain_folder(tmp_path, name, text):
    folder = write_folder(tmp_path / "video", n=12, intrinsics=name, text=text)
    seq = open_sequence(folder)
    assert seq.layout == "folder" and len(seq) == 12 and seq.cameras[0].size == (H, W)
    assert [p.name for p in seq.cameras[0].images[:3]] == ["frame_1.png", "frame_2.png", "frame_3.png"]
    np.testing.assert_allclose(seq.cameras[0].K, K, atol=1e-12)


def test_plain_folder_with_explicit_intrinsics(tmp_path):
    folder = write_folder(tmp_path / "video", intrinsics="elsewhere.txt")
    assert detect_layout(folder) is None
    seq = open_sequence(folder, intrinsics=folder / "elsewhere.txt")
    np.testing.assert_allclose(seq.cameras[0].K, K)
    assert find_sequences(folder) == [folder]


def test_find_sequences_in_a_date_folder(tmp_path):
    truth = write_kitti_raw(tmp_path, n=2)
    assert find_sequences(tmp_path / "2011_09_26") == [truth["drive"]]
