"""Pose files: KITTI, TUM and EuRoC / ASL CSV reading, writing, auto-detection, validation."""

import cv2
import numpy as np
import pytest
import torch

from ocalib.errors import InputError
from ocalib.io.poses import (
    Trajectory,
    describe_invalid,
    pose_validity,
    read_euroc,
    read_kitti,
    read_poses,
    read_times,
    read_tum,
    write_kitti,
    write_tum,
)

TUM_LINE = "{t} 1 2 3 0 0 0 1"  # identity rotation (qw last)
KITTI_LINE = "1 0 0 1 0 1 0 2 0 0 1 3"


def write(tmp_path, text, name="poses.txt"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_tum_round_trip(tmp_path, rig):
    times, poses, _, _ = rig(duration=3.0)
    times = times + 1.7e9  # Unix time keeps its sub-microsecond digits
    write_tum(tmp_path / "cam.tum", times, torch.from_numpy(poses))
    traj = read_tum(tmp_path / "cam.tum")
    assert isinstance(traj, Trajectory) and len(traj) == len(poses)
    np.testing.assert_allclose(traj.times, times, rtol=0, atol=1e-6)
    np.testing.assert_allclose(traj.poses, poses, rtol=0, atol=1e-8)
    assert traj.lines[0] == 2  # after the header comment
    auto = read_poses(tmp_path / "cam.tum")
    np.testing.assert_array_equal(auto.poses, traj.poses)


def test_kitti_round_trip_and_times(tmp_path, rig):
    _, poses, _, _ = rig(duration=1.0)
    write_kitti(tmp_path / "cam.txt", poses)
    np.testing.assert_allclose(read_kitti(tmp_path / "cam.txt"), poses, rtol=0, atol=1e-8)
    traj = read_poses(tmp_path / "cam.txt")
    assert traj.times is None and traj.path == tmp_path / "cam.txt"
    np.testing.assert_allclose(traj.poses, poses, rtol=0, atol=1e-8)
    times = write(tmp_path, "".join(f"{0.1 * i:.6e}\n" for i in range(len(poses))), "times.txt")
    traj = read_poses(tmp_path / "cam.txt", times=times)
    np.testing.assert_allclose(traj.times, 0.1 * np.arange(len(poses)))


def test_tum_quaternion_is_xyzw_and_normalised(tmp_path):
    s = np.sin(np.pi / 4)
    path = write(tmp_path, f"0.5 1 2 3 0 0 {2 * s} {2 * s}\n")  # 90 deg about z, norm 2
    traj = read_tum(path)
    expected = np.array([[0, -1, 0, 1], [1, 0, 0, 2], [0, 0, 1, 3], [0, 0, 0, 1.0]])
    np.testing.assert_allclose(traj.poses[0], expected, atol=1e-12)
    np.testing.assert_array_equal(traj.times, [0.5])


def test_comma_separated_comments_and_blank_lines(tmp_path):
    text = "# time, x, y, z, qx, qy, qz, qw\n\n1.0,1,2,3,0,0,0,1\n  # more\n2.0, 1, 2, 3, 0, 0, 0, 1\n\n"
    path = write(tmp_path, text)
    traj = read_poses(path)
    np.testing.assert_array_equal(traj.times, [1.0, 2.0])
    np.testing.assert_array_equal(traj.lines, [3, 5])
    np.testing.assert_allclose(traj.poses[:, :3, 3], [[1, 2, 3]] * 2)


def test_auto_detection(tmp_path):
    assert read_poses(write(tmp_path, KITTI_LINE + "\n", "k.txt")).times is None
    assert read_poses(write(tmp_path, TUM_LINE.format(t=1) + "\n", "t.txt")).times is not None
    path = write(tmp_path, "# header\n1 2 3 4 5 6 7\n")
    with pytest.raises(InputError, match=rf"{path}:2: .*7 numbers.*12 \(KITTI.*8 \(TUM"):
        read_poses(path)
    with pytest.raises(InputError, match=rf"{path}:2: expected 12 numbers"):
        read_poses(path, format="kitti")


@pytest.mark.parametrize(
    "text, line, message",
    [
        (f"{TUM_LINE.format(t=1)}\n{TUM_LINE.format(t=2)}\nhello world\n", 3, "not a number"),
        (f"{TUM_LINE.format(t=1)}\n# c\n1 2 3 4 5 6 7 8 9 10 11 12\n", 3, "expected 8 numbers"),
        (f"{TUM_LINE.format(t=1)}\n{TUM_LINE.format(t=1)}\n", 2, "duplicate timestamp"),
        (
            f"{TUM_LINE.format(t=1)}\n{TUM_LINE.format(t=3)}\n{TUM_LINE.format(t=2)}\n",
            3,
            "timestamp goes back in time: 2.0 after 3.0 at line 2",
        ),
        (f"{TUM_LINE.format(t=1)}\n{TUM_LINE.format(t='nan')}\n", 2, "timestamp is nan"),
        (f"{TUM_LINE.format(t=1)}\n2 1 2 3 0 0 0 1e-9\n", 2, "quaternion .* has norm"),
        (f"{TUM_LINE.format(t=1)}\n2 1 2 3 0 0 0\n", 2, "expected 8 numbers"),
    ],
)
def test_bad_tum_files_name_file_and_line(tmp_path, text, line, message):
    path = write(tmp_path, text)
    for fmt in ("auto", "tum"):
        with pytest.raises(InputError, match=rf"{path}:{line}: {message}"):
            read_poses(path, format=fmt)


@pytest.mark.parametrize("text", ["", "\n\n", "# only a comment\n"])
def test_empty_files(tmp_path, text):
    path = write(tmp_path, text)
    for read in (read_poses, read_kitti, read_tum):
        with pytest.raises(InputError, match=rf"{path}: no poses"):
            read(path)


def test_bad_kitti_files_and_times(tmp_path):
    path = write(tmp_path, f"{KITTI_LINE}\n1 0 0 1 0 1 x 2 0 0 1 3\n")
    with pytest.raises(InputError, match=rf"{path}:2: not a number"):
        read_kitti(path)
    path = write(tmp_path, f"{KITTI_LINE}\n{KITTI_LINE}\n", "k.txt")
    times = write(tmp_path, "0.0\n0.1\n0.2\n", "times.txt")
    with pytest.raises(InputError, match=rf"{times}: 3 timestamps for the 2 poses of {path}"):
        read_poses(path, times=times)
    times = write(tmp_path, "0.0\n0.0\n", "times.txt")
    with pytest.raises(InputError, match=rf"{times}:2: duplicate timestamp"):
        read_times(times)
    tum = write(tmp_path, TUM_LINE.format(t=1) + "\n", "t.txt")
    with pytest.raises(InputError, match="carries its own timestamps"):
        read_poses(tum, times=times)
    with pytest.raises(InputError, match="unknown pose format 'csv'"):
        read_poses(path, format="csv")


def test_invalid_poses_are_read_flagged_and_described(tmp_path):
    lines = [KITTI_LINE] * 6
    lines[1] = "nan 0 0 1 0 1 0 2 0 0 1 3"
    lines[3] = "1 0 0 1 0 1 0 2 0 0 1.01 3"  # not orthonormal
    lines[4] = "1 0 0 1 0 1 0 2 0 0 -1 3"  # a reflection, det -1
    path = write(tmp_path, "# header\n" + "\n".join(lines) + "\n")
    traj = read_poses(path)
    mask = pose_validity(traj.poses)
    np.testing.assert_array_equal(mask, [True, False, True, False, False, True])
    np.testing.assert_array_equal(pose_validity(torch.from_numpy(traj.poses)), mask)
    assert describe_invalid(path, mask, traj.lines) == (
        f"{path}: 3 of 6 poses invalid at lines 3, 5, 6 (NaN/inf or non-orthonormal rotation)"
    )
    one = describe_invalid(path, mask[:2])
    assert one == f"{path}: 1 of 2 poses invalid at line 2 (NaN/inf or non-orthonormal rotation)"
    assert describe_invalid(path, mask[[0, 2, 5]]) is None
    many = describe_invalid("cam1.txt", np.zeros(25, bool), shown=3)
    assert many.startswith("cam1.txt: 25 of 25 poses invalid at lines 1, 2, 3 and 22 more")


def test_tum_nan_pose_is_not_a_read_error(tmp_path):
    path = write(tmp_path, f"{TUM_LINE.format(t=1)}\n2 nan 2 3 0 0 0 1\n3 1 2 3 nan 0 0 1\n")
    traj = read_tum(path)
    np.testing.assert_array_equal(pose_validity(traj.poses), [True, False, False])
    assert pose_validity(traj.poses, tol=1e-3).dtype == bool


EUROC_HEADER = (
    "#timestamp [ns],p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],q_RS_y [],q_RS_z [],"
    "v_RS_R_x [m s^-1],v_RS_R_y [m s^-1],v_RS_R_z [m s^-1],b_w_RS_S_x [rad s^-1],b_w_RS_S_y [rad s^-1],"
    "b_w_RS_S_z [rad s^-1],b_a_RS_S_x [m s^-2],b_a_RS_S_y [m s^-2],b_a_RS_S_z [m s^-2]"
)


def euroc_file(tmp_path, name, header, extra=9, n=20, seed=0):
    """An EuRoC-style CSV of n random poses (cv2.Rodrigues -> matrices, the reference) -> (path, poses, seconds)."""
    rng = np.random.default_rng(seed)
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, 3] = rng.normal(size=(n, 3))
    for T in poses:
        T[:3, :3] = cv2.Rodrigues(rng.normal(size=3))[0]
    q = torch.tensor(np.stack([_quaternion_wxyz(T[:3, :3]) for T in poses]))
    stamps = 1403636579758555392 + np.arange(n, dtype=np.int64) * 5_000_000  # ns, 200 Hz
    lines = [header] if header else []
    for t, T, qq in zip(stamps, poses, q.numpy()):
        lines.append(",".join([str(t), *(f"{v:.12f}" for v in (*T[:3, 3], *qq)), *(["0.1"] * extra)]))
    path = write(tmp_path, "\n".join(lines) + "\n", name)
    return path, poses, stamps * 1e-9


def _quaternion_wxyz(R):
    """(w, x, y, z) of R from its rotation vector (an independent route to the file's numbers)."""
    v = cv2.Rodrigues(R)[0].ravel()
    angle = np.linalg.norm(v)
    axis = v / angle if angle > 0 else v
    return np.r_[np.cos(angle / 2), np.sin(angle / 2) * axis]


@pytest.mark.parametrize("header, extra", [(EUROC_HEADER, 9), ("# t px py pz qw qx qy qz", 0)])
def test_euroc_is_detected_from_its_header(tmp_path, header, extra):
    path, poses, seconds = euroc_file(tmp_path, "gt.csv", header, extra)
    traj = read_poses(path)
    np.testing.assert_allclose(traj.poses, poses, atol=1e-9)
    np.testing.assert_allclose(traj.times, seconds, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(traj.lines, np.arange(2, 22))
    np.testing.assert_allclose(read_euroc(path).poses, poses, atol=1e-9)


def test_headerless_nanosecond_files_need_a_format(tmp_path):
    path, poses, _ = euroc_file(tmp_path, "vio.csv", None, extra=0)
    with pytest.raises(
        InputError,
        match=rf"{path}:1: .*nanoseconds.*For EuRoC start the file with EuRoC.s header.*--format euroc.*--format tum",
    ):
        read_poses(path)
    np.testing.assert_allclose(read_poses(path, format="euroc").poses, poses, atol=1e-9)
    path, poses, _ = euroc_file(tmp_path, "vio17.csv", None, extra=9)
    with pytest.raises(InputError, match=r"17 numbers.*--format euroc"):
        read_poses(path)
    np.testing.assert_allclose(read_poses(path, format="euroc").poses, poses, atol=1e-9)
    with pytest.raises(InputError, match=r"needs at least 8"):
        read_euroc(write(tmp_path, "1 2 3 4 5 6 7\n", "short.csv"))


def test_times_in_nanoseconds_are_read_as_seconds(tmp_path):
    ns = write(tmp_path, "1700000000000000000\n1700000000100000000\n1700000000250000000\n", "times.txt")
    np.testing.assert_allclose(read_times(ns), [1.7e9, 1.7e9 + 0.1, 1.7e9 + 0.25], rtol=0, atol=1e-6)
    seconds = write(tmp_path, "1700000000.0\n1700000000.1\n", "s.txt")
    np.testing.assert_allclose(read_times(seconds), [1.7e9, 1.7e9 + 0.1], rtol=0, atol=1e-9)
    mixed = write(tmp_path, "1700000000000000000\n1700000000.1\n", "m.txt")
    with pytest.raises(InputError, match=rf"{mixed}:2: stamp 1700000000.1 is in seconds, the first .* nanoseconds"):
        read_times(mixed)
