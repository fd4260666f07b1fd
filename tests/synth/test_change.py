"""A camera knocked out of place mid-sequence: poses, rig.yaml and images follow the mounting in force."""

import copy

import cv2
import numpy as np
import pytest
import torch
import yaml
from scipy.spatial.transform import Rotation

from ocalib.data.layout import open_sequence
from ocalib.data.rig import read_rig_yaml
from ocalib.errors import InputError
from ocalib.io.poses import read_kitti
from ocalib.synth import PRESETS, camera_poses, config_from_dict, load_config, render_rig, render_sequence
from ocalib.synth.writer import to_rgb8

TINY = dict(frames=8, height=32, width=96)
CHANGE = {"frame": 4, "rotation_deg": [3.0, 125.0, -2.0], "position": [0.15, 0.02, -0.04]}


def handheld(change=None):
    data = copy.deepcopy(PRESETS["handheld"])
    if change is not None:
        data["cameras"][1]["change"] = change
    return config_from_dict(data, "handheld").with_overrides(**TINY)


def extrinsic(rotation_deg, position):
    """T_cam0_cam from the config's convention R = Rz Ry Rx (intrinsic z-y-x Euler angles)."""
    rx, ry, rz = rotation_deg
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("ZYX", [rz, ry, rx], degrees=True).as_matrix()
    T[:3, 3] = position
    return T


BEFORE = extrinsic([0.0, 120.0, 0.0], [0.12, 0.0, -0.05])  # the preset's camera 1
AFTER = extrinsic(CHANGE["rotation_deg"], CHANGE["position"])


def relative(poses):
    """inv(pose_cam0[t]) @ pose_cam1[t] (N, 4, 4) of poses (2, N, 4, 4)."""
    return np.linalg.inv(poses[0]) @ poses[1]


def test_config_extrinsic_at_each_frame():
    cam = handheld(CHANGE).cameras[1]
    assert np.abs(cam.T_cam0_cam() - BEFORE).max() < 1e-12
    assert np.abs(cam.T_cam0_cam(3) - BEFORE).max() < 1e-12
    assert np.abs(cam.T_cam0_cam(4) - AFTER).max() < 1e-12
    expected = np.stack([BEFORE] * 4 + [AFTER] * 4)
    assert np.abs(cam.extrinsics(8) - expected).max() < 1e-12
    assert np.abs(handheld().cameras[1].extrinsics(8) - BEFORE).max() < 1e-12


def test_poses_follow_the_change():
    rel = relative(camera_poses(handheld(CHANGE)))
    assert np.abs(rel[:4] - BEFORE).max() < 1e-9
    assert np.abs(rel[4:] - AFTER).max() < 1e-9
    assert np.array_equal(camera_poses(handheld(CHANGE))[0], camera_poses(handheld())[0])  # camera 0 untouched


def test_rendered_layout_holds_the_truth(tmp_path):
    cfg = handheld(CHANGE)
    out = render_sequence(cfg, tmp_path / "seq", progress=False)
    written = np.stack([read_kitti(out / name / "poses.txt") for name in ["cam0", "cam1"]])
    rel = relative(written)
    assert np.abs(rel[:4] - BEFORE).max() < 1e-6  # poses.txt keeps 10 significant digits
    assert np.abs(rel[4:] - AFTER).max() < 1e-6

    rig = read_rig_yaml(out / "rig.yaml")
    assert rig.cameras[0].change is None
    change = rig.cameras[1].change
    assert change.frame == 4 and np.abs(change.T_cam0_cam - AFTER).max() < 1e-12
    assert np.abs(rig.cameras[1].T_cam0_cam - BEFORE).max() < 1e-12

    seq = open_sequence(out)
    assert seq.camera("cam0").change is None
    assert seq.camera("cam1").change.frame == 4
    assert np.abs(seq.camera("cam1").change.T_cam0_cam - AFTER).max() < 1e-12
    assert np.abs(seq.camera("cam1").T_cam0_cam - BEFORE).max() < 1e-12

    # the images: camera 1 sees what the unchanged rig sees before frame 4 and something else from then on
    plain = render_rig(handheld())
    for t in range(8):
        image = cv2.cvtColor(cv2.imread(str(out / "cam1" / "images" / f"{t:06d}.png")), cv2.COLOR_BGR2RGB)
        same = np.array_equal(image, to_rgb8(plain.images[1, t]))
        assert same == (t < 4), t


def test_in_memory_render_uses_the_change():
    seq = render_rig(handheld(CHANGE).with_overrides(frames=5))
    rel = relative(seq.poses.numpy())
    assert np.abs(rel[:4] - BEFORE).max() < 1e-9 and np.abs(rel[4] - AFTER).max() < 1e-9
    assert seq.rig.cameras[1].change.frame == 4
    assert not torch.equal(seq.images[1, 4], render_rig(handheld().with_overrides(frames=5)).images[1, 4])


def test_config_round_trip_with_change(tmp_path):
    cfg = handheld(CHANGE)
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(cfg.to_dict()))
    assert load_config(path) == cfg


HEAD = "name: x\nframes: 8\ncameras:\n  - {name: a}\n"


@pytest.mark.parametrize(
    "text, message",
    [
        (
            "name: x\nframes: 8\ncameras:\n  - {name: a, change: {frame: 2, rotation_deg: [0, 0, 0], "
            "position: [0, 0, 0]}}\n",
            "camera 0 (a) defines the rig frame",
        ),
        (HEAD + "  - {name: b, change: [4, 0, 0]}\n", "camera b: change: expected a mapping"),
        (HEAD + "  - {name: b, change: {frame: 4, rotation_deg: [0, 0, 0]}}\n", "camera b: change: missing position"),
        (
            HEAD + "  - {name: b, change: {frame: 4, rotation_deg: [0, 0, 0], position: [0, 0, 0], when: 3}}\n",
            "camera b: change: unknown key(s) when",
        ),
        (HEAD + "  - {name: b, change: {frame: 0, rotation_deg: [0, 0, 0], position: [0, 0, 0]}}\n", "frame must be"),
        (HEAD + "  - {name: b, change: {frame: 8, rotation_deg: [0, 0, 0], position: [0, 0, 0]}}\n", "in [1, 7]"),
        (HEAD + "  - {name: b, change: {frame: 2.5, rotation_deg: [0, 0, 0], position: [0, 0, 0]}}\n", "frame must"),
        (HEAD + "  - {name: b, change: {frame: '4', rotation_deg: [0, 0, 0], position: [0, 0, 0]}}\n", "frame must"),
        (HEAD + "  - {name: b, change: {frame: true, rotation_deg: [0, 0, 0], position: [0, 0, 0]}}\n", "frame must"),
        (
            HEAD + "  - {name: b, change: {frame: 4, rotation_deg: [0, 0], position: [0, 0, 0]}}\n",
            "camera b: change: rotation_deg needs 3 finite numbers",
        ),
        (
            HEAD + "  - {name: b, change: {frame: 4, rotation_deg: [0, 0, 0], position: [0, .nan, 0]}}\n",
            "camera b: change: position needs 3 finite numbers",
        ),
        (
            HEAD + "  - {name: b, change: {frame: 4, rotation_deg: [0, 0, 0], position: [0, up, 0]}}\n",
            "position needs 3 finite numbers",
        ),
    ],
)
def test_bad_change_is_one_clear_line(tmp_path, text, message):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(InputError) as info:
        load_config(path)
    err = str(info.value)
    assert message in err and str(path) in err and len(err.splitlines()) == 1, err


def test_fewer_frames_than_the_change_is_refused():
    with pytest.raises(InputError, match=r"camera cam1: change: frame must be an integer in \[1, 3\]"):
        handheld(CHANGE).with_overrides(frames=4)
