"""Bad input: each case is an InputError whose message names the file at fault."""

import pytest
from data_fixtures import (
    noise_image,
    write_folder,
    write_kitti_odometry,
    write_kitti_raw,
    write_png,
    write_rig,
    write_sfmlearner,
)

from ocalib.data import RigStream, SnippetDataset, find_sequences, open_sequence
from ocalib.errors import InputError


def raises_naming(path, func, *args, **kwargs):
    with pytest.raises(InputError) as err:
        func(*args, **kwargs)
    assert str(path) in str(err.value), str(err.value)
    return str(err.value)


def test_gap_in_numbering(tmp_path):
    write_rig(tmp_path, n=5)
    missing = tmp_path / "cam1" / "images" / "000002.png"
    missing.unlink()
    assert "missing" in raises_naming(missing, open_sequence, tmp_path)


def test_camera_missing_a_frame(tmp_path):
    drive = write_kitti_raw(tmp_path, n=4)["drive"]
    middle = drive / "image_01" / "data" / "0000000001.png"
    middle.unlink()
    raises_naming(middle, open_sequence, drive)
    write_png(middle, noise_image(0, grey=True))
    last = drive / "image_02" / "data" / "0000000003.png"
    last.unlink()
    assert "image_00" in raises_naming(last, open_sequence, drive)


def test_unequal_frame_counts(tmp_path):
    write_rig(tmp_path, n=4, depth=False)
    write_png(tmp_path / "cam1" / "images" / "000004.png", noise_image(9))
    raises_naming(tmp_path / "cam0" / "images" / "000004.png", open_sequence, tmp_path)


def test_unequal_counts_of_unnumbered_frames(tmp_path):
    folder = write_folder(tmp_path / "video", n=4)
    (folder / "poses.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 0\n")
    raises_naming(folder / "poses.txt", open_sequence, folder)


def test_oxts_count_differs(tmp_path):
    drive = write_kitti_raw(tmp_path, n=3)["drive"]
    (drive / "oxts" / "data" / "0000000002.txt").unlink()
    raises_naming(drive / "oxts" / "data", open_sequence, drive)


@pytest.mark.parametrize("content", [b"", b"not a png at all", b"\x89PNG\r\n\x1a\n" + bytes(40)])
def test_unreadable_image(tmp_path, content):
    write_rig(tmp_path, n=3)
    bad = tmp_path / "cam0" / "images" / "000001.png"
    bad.write_bytes(content)
    seq = open_sequence(tmp_path)  # images are read lazily
    assert "cannot read" in raises_naming(bad, lambda: SnippetDataset([seq])[0])
    raises_naming(bad, lambda: RigStream(seq)[1])


def test_image_of_the_wrong_size(tmp_path):
    write_rig(tmp_path, n=3)
    bad = write_png(tmp_path / "cam1" / "images" / "000000.png", noise_image(0, size=(20, 80)))
    raises_naming(bad, lambda: RigStream(open_sequence(tmp_path))[0])


@pytest.mark.parametrize("line", ["P_rect_02: 1 2 x 4", "P_rect_02: 1 2 3", "P_rect_02 1 2 3"])
def test_malformed_kitti_raw_calibration(tmp_path, line):
    drive = write_kitti_raw(tmp_path, n=2)["drive"]
    calib = drive.parent / "calib_cam_to_cam.txt"
    calib.write_text("\n".join(line if l.startswith("P_rect_02") else l for l in calib.read_text().splitlines()))
    raises_naming(calib, open_sequence, drive)


def test_malformed_rigid_calibration_and_oxts(tmp_path):
    drive = write_kitti_raw(tmp_path, n=2)["drive"]
    velo = drive.parent / "calib_velo_to_cam.txt"
    text = velo.read_text()
    velo.write_text(text.replace("R:", "Q:"))
    assert "'R'" in raises_naming(velo, open_sequence, drive)
    velo.write_text(text)
    packet = drive / "oxts" / "data" / "0000000001.txt"
    packet.write_text("49.0 8.4 110\n")
    raises_naming(packet, open_sequence, drive)
    stamps = drive / "image_00" / "timestamps.txt"
    stamps.write_text("yesterday\n")
    raises_naming(stamps, open_sequence, drive)


def test_malformed_odometry_calibration_and_poses(tmp_path):
    folder = write_kitti_odometry(tmp_path, n=3)
    calib = folder / "calib.txt"
    text = calib.read_text()
    calib.write_text(text.replace("P2:", "P2: 1"))
    assert ":3:" in raises_naming(calib, open_sequence, folder)  # file:line
    calib.write_text(text)
    poses = tmp_path / "dataset" / "poses" / "00.txt"
    poses.write_text(poses.read_text() + "1 2 3\n")
    raises_naming(poses, open_sequence, folder)


@pytest.mark.parametrize(
    "name,text",
    [
        ("cam.txt", "50 0 39.5\n0 50 11.5\n0 0\n"),
        ("cam.txt", "50 0 39.5\n0 50 eleven\n0 0 1\n"),
        ("cam.txt", "-50 0 39.5\n0 50 11.5\n0 0 1\n"),
        ("intrinsics.yaml", "fx: 50\nfy: 50\ncx: 39.5\n"),
        ("intrinsics.yaml", "K: [[50, 0, 39.5], [0, 50, 11.5]]\n"),
        ("intrinsics.yaml", "fx: [50\n"),
    ],
)
def test_malformed_intrinsics(tmp_path, name, text):
    folder = write_folder(tmp_path / "video", intrinsics=name, text=text)
    raises_naming(folder / name, open_sequence, folder)


def test_malformed_rig_yaml(tmp_path):
    write_rig(tmp_path, n=2)
    (tmp_path / "rig.yaml").write_text("cameras: [{name: cam0, width: 80}]\n")
    raises_naming(tmp_path / "rig.yaml", open_sequence, tmp_path)


def test_empty_folders(tmp_path):
    (tmp_path / "empty").mkdir()
    assert "empty" in raises_naming(tmp_path / "empty", open_sequence, tmp_path / "empty")
    raises_naming(tmp_path / "empty", find_sequences, tmp_path / "empty")
    write_rig(tmp_path / "rig", n=2)
    for png in (tmp_path / "rig" / "cam1" / "images").iterdir():
        png.unlink()
    raises_naming(tmp_path / "rig" / "cam1" / "images", open_sequence, tmp_path / "rig")


def test_split_naming_a_missing_scene(tmp_path):
    root = write_sfmlearner(tmp_path)
    (root / "val.txt").write_text("nowhere\n")
    raises_naming(root / "val.txt", find_sequences, root / "val.txt")


def test_unknown_layout_and_missing_path(tmp_path):
    write_png(tmp_path / "x" / "a.png", noise_image(0))
    assert "intrinsics" in raises_naming(tmp_path / "x", open_sequence, tmp_path / "x")
    raises_naming(tmp_path / "nope", open_sequence, tmp_path / "nope")


def test_a_rig_without_rig_yaml_is_told_to_write_one(tmp_path):
    for cam in ("cam0", "cam1"):
        write_png(tmp_path / "rig" / cam / "images" / "000000.png", noise_image(0))
    message = raises_naming(tmp_path / "rig", open_sequence, tmp_path / "rig")
    assert f"needs {tmp_path / 'rig' / 'rig.yaml'}" in message and "intrinsics file" not in message


def test_duplicate_frame_number(tmp_path):
    write_rig(tmp_path, n=3)
    write_png(tmp_path / "cam0" / "images" / "000001.jpg", noise_image(0))
    assert "twice" in raises_naming(tmp_path / "cam0" / "images", open_sequence, tmp_path)
