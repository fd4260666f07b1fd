"""rig.yaml ``change`` entries: written and read back, carried to the sequence, clear errors when bad."""

import numpy as np
import pytest
import yaml
from data_fixtures import H, K, W, pose, rot, write_rig

from ocalib.data import open_sequence
from ocalib.data.rig import CameraSpec, ExtrinsicChange, RigSpec, read_rig_yaml, write_rig_yaml
from ocalib.data.sequence import Camera, Sequence
from ocalib.errors import InputError

BEFORE = pose(rot(1, np.pi), (0.2, 0.0, -0.5))  # write_rig's camera 1
AFTER = pose(rot(1, np.pi - 0.1) @ rot(0, 0.03), (0.25, 0.01, -0.5))


def add_change(root, change):
    """Rewrite root/rig.yaml with ``change`` under camera 1."""
    data = yaml.safe_load((root / "rig.yaml").read_text())
    data["cameras"][1]["change"] = change
    (root / "rig.yaml").write_text(yaml.safe_dump(data))


def test_round_trip(tmp_path):
    cams = [CameraSpec("cam0", W, H, K, np.eye(4)), CameraSpec("cam1", W, H, K, BEFORE, ExtrinsicChange(3, AFTER))]
    write_rig_yaml(tmp_path / "rig.yaml", RigSpec(cams, 10.0))
    entry = yaml.safe_load((tmp_path / "rig.yaml").read_text())["cameras"][1]["change"]
    assert entry["frame"] == 3 and np.array_equal(entry["T_cam0_cam"], AFTER)
    rig = read_rig_yaml(tmp_path / "rig.yaml")
    assert rig.cameras[0].change is None
    assert rig.cameras[1].change.frame == 3
    assert np.array_equal(rig.cameras[1].change.T_cam0_cam, AFTER)
    assert np.array_equal(rig.cameras[1].T_cam0_cam, BEFORE)


def test_sequence_cameras_carry_the_change(tmp_path):
    write_rig(tmp_path, n=5)
    add_change(tmp_path, {"frame": 3, "T_cam0_cam": AFTER.tolist()})
    seq = open_sequence(tmp_path)
    assert seq.camera("cam0").change is None
    change = seq.camera("cam1").change
    assert change.frame == 3 and np.abs(change.T_cam0_cam - AFTER).max() < 1e-12


def test_selection_rereferences_the_change(tmp_path):
    write_rig(tmp_path, n=5)
    add_change(tmp_path, {"frame": 3, "T_cam0_cam": AFTER.tolist()})
    seq = open_sequence(tmp_path, cameras=["cam1", "cam0"])  # the moving camera as the reference
    assert seq.cameras[0].change is None
    assert seq.cameras[1].change.frame == 3
    assert np.abs(seq.cameras[1].change.T_cam0_cam - np.linalg.inv(AFTER)).max() < 1e-12
    assert np.abs(seq.cameras[1].T_cam0_cam - np.linalg.inv(BEFORE)).max() < 1e-12


def test_selection_refuses_a_reference_moving_at_another_frame(tmp_path):
    images = [tmp_path / f"{t:06d}.png" for t in range(5)]
    moved = pose(rot(1, 0.6), (-0.3, 0, 0))
    cams = [
        Camera("cam0", images, K, (H, W), np.eye(4)),
        Camera("cam1", images, K, (H, W), BEFORE, change=ExtrinsicChange(3, AFTER)),
        Camera("cam2", images, K, (H, W), pose(rot(1, 0.5)), change=ExtrinsicChange(2, moved)),
    ]
    seq = Sequence("s", tmp_path, "rig", cams)
    same = seq.select(["cam2", "cam0"])  # cam0 never moves: relative to cam2 it moves at frame 2
    assert same.cameras[1].change.frame == 2
    assert np.abs(same.cameras[1].change.T_cam0_cam - np.linalg.inv(moved)).max() < 1e-12
    with pytest.raises(InputError, match="move at different frames"):
        seq.select(["cam2", "cam1"])


GOOD_T = np.eye(4).tolist()


@pytest.mark.parametrize(
    "change, message",
    [
        ([3, GOOD_T], "change must be a mapping with exactly frame and T_cam0_cam"),
        ({"frame": 3}, "change must be a mapping with exactly frame and T_cam0_cam"),
        ({"frame": 3, "T_cam0_cam": GOOD_T, "why": "bump"}, "change must be a mapping with exactly"),
        ({"frame": 0, "T_cam0_cam": GOOD_T}, "change.frame must be an integer >= 1"),
        ({"frame": 2.5, "T_cam0_cam": GOOD_T}, "change.frame must be an integer >= 1"),
        ({"frame": True, "T_cam0_cam": GOOD_T}, "change.frame must be an integer >= 1"),
        ({"frame": 3, "T_cam0_cam": np.eye(3).tolist()}, "change.T_cam0_cam must be 4x4"),
        ({"frame": 3, "T_cam0_cam": [[1, 0, 0, "x"]] * 4}, "change.T_cam0_cam must be 4x4"),
        ({"frame": 3, "T_cam0_cam": (np.eye(4) * np.nan).tolist()}, "change.T_cam0_cam must be 4x4"),
        ({"frame": 5, "T_cam0_cam": GOOD_T}, "change.frame 5 is past the last frame (5 frames)"),
    ],
)
def test_bad_change_is_one_clear_line(tmp_path, change, message):
    write_rig(tmp_path, n=5)
    add_change(tmp_path, change)
    with pytest.raises(InputError) as info:
        open_sequence(tmp_path)
    err = str(info.value)
    assert message in err and str(tmp_path / "rig.yaml") in err and "cam1" in err and len(err.splitlines()) == 1, err


def test_change_on_camera_0_or_without_an_extrinsic_is_refused(tmp_path):
    write_rig(tmp_path, n=5)
    data = yaml.safe_load((tmp_path / "rig.yaml").read_text())
    data["cameras"][0]["change"] = {"frame": 2, "T_cam0_cam": GOOD_T}
    (tmp_path / "rig.yaml").write_text(yaml.safe_dump(data))
    with pytest.raises(InputError, match=r"cameras\[0\] \(cam0\): change: camera 0 defines the rig frame"):
        read_rig_yaml(tmp_path / "rig.yaml")
    del data["cameras"][0]["change"]
    del data["cameras"][1]["T_cam0_cam"]
    data["cameras"][1]["change"] = {"frame": 2, "T_cam0_cam": GOOD_T}
    (tmp_path / "rig.yaml").write_text(yaml.safe_dump(data))
    with pytest.raises(InputError, match=r"cameras\[1\] \(cam1\): change needs the camera's T_cam0_cam"):
        read_rig_yaml(tmp_path / "rig.yaml")
