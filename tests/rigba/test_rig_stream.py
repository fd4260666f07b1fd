"""The on-line rig estimator's stage in ``ocalib calibrate``: each camera's image placed at the rig's pose when that
camera captured it, where the cameras run on clocks of their own."""

from types import SimpleNamespace

import cv2
import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from ocalib.calib.drivers.change import Change
from ocalib.calib.poses.report import CalibrationRun
from ocalib.data.synchronise import Pairing
from ocalib.rigba.camera_state import CameraState
from ocalib.rigba.change import UNINFORMED, ExtrinsicTrack
from ocalib.rigba.online import OnlineRigOptions
from ocalib.rigba.stream import OnlineRigStage, capture_poses


def _trajectory(times: np.ndarray) -> np.ndarray:
    """A rig driving along x at 8 m/s while turning at 20 deg/s about y: poses (N, 4, 4) at ``times``."""
    out = np.tile(np.eye(4), (len(times), 1, 1))
    out[:, :3, :3] = Rotation.from_rotvec(np.radians(20.0) * times[:, None] * [0, 1, 0]).as_matrix()
    out[:, 0, 3] = 8.0 * times
    return out


def test_a_late_camera_is_placed_at_the_rigs_pose_when_it_captured():
    times = np.arange(20) / 10.0
    late = np.where(np.arange(20) % 2, 0.05, -0.04)  # camera 1's capture, seconds after camera 0's (either way)
    pairing = Pairing(np.array([0.0, 0.05]), np.tile(np.arange(20)[:, None], (1, 2)), np.c_[np.zeros(20), -late],
                      np.array([20, 20]))  # fmt: skip
    sequence = SimpleNamespace(cameras=[None, None], names=["cam0", "cam1"], times=times, pairing=pairing)
    poses = capture_poses(sequence, _trajectory(times))
    np.testing.assert_array_equal(poses[:, 0], _trajectory(times))  # camera 0's as given
    inside = (times + late >= 0) & (times + late <= times[-1])  # camera 0's frames bracket the capture
    np.testing.assert_allclose(poses[inside, 1], _trajectory(times + late)[inside], atol=1e-9)
    np.testing.assert_array_equal(poses[~inside, 1], _trajectory(times)[~inside])  # outside: camera 0's
    stream = OnlineRigStage(sequence, _trajectory(times))  # the default: a trajectory's noise stated
    assert not stream.solves_poses  # each camera at its own capture pose: only held poses allow it


def test_cameras_a_millisecond_apart_share_the_rigs_pose_and_the_window_solves_it():
    """Camera 1 capturing 1 ms after camera 0 (the rig moves 8 mm and turns 0.02 deg in between: under a fifth of the
    trajectory's 5 cm noise): its poses are camera 0's and the window solves the rig's poses; 5 ms apart (4 cm), each
    camera at its own capture pose, held."""
    times = np.arange(20) / 10.0
    for late, shared in ((0.001, True), (0.005, False)):
        pairing = Pairing(np.array([0.0, late]), np.tile(np.arange(20)[:, None], (1, 2)),
                          np.c_[np.zeros(20), np.full(20, -late)], np.array([20, 20]))  # fmt: skip
        sequence = SimpleNamespace(cameras=[None, None], names=["cam0", "cam1"], times=times, pairing=pairing)
        stream = OnlineRigStage(sequence, _trajectory(times))
        assert stream.solves_poses == shared and (stream.capture[:, 1] == stream.capture[:, 0]).all() == shared
        assert (capture_poses(sequence, _trajectory(times))[:-1, 1] != _trajectory(times)[:-1]).any()  # no noise given


def test_synchronised_cameras_share_the_rigs_pose():
    times = np.arange(5) / 10.0
    sequence = SimpleNamespace(cameras=[None, None, None], names=["a", "b", "c"], times=times, pairing=None)
    poses = capture_poses(sequence, _trajectory(times))
    assert poses.shape == (5, 3, 4, 4) and (poses == _trajectory(times)[:, None]).all()
    assert OnlineRigStage(sequence, _trajectory(times)).solves_poses
    assert not OnlineRigStage(sequence, _trajectory(times), OnlineRigOptions(metric_noise=0.0)).solves_poses


def test_the_final_errors_leave_out_the_axes_the_data_do_not_inform():
    """A car's camera height (its 1-sigma over a tenth of the lever arm, as the bundle adjustment's rule) is not
    compared: 1 m off in y, exact in x and z, is no error; the same estimate with every axis pinned is compared in
    3-D (against a hand computation), unless the drive is planar (the ground plane's normal given)."""
    truth = np.stack([np.eye(4), np.eye(4)])
    truth[1, :3, 3] = [1.2, 0.3, -0.5]
    E = truth.copy()
    E[1, 1, 3] += 1.0
    std = np.zeros((2, 6))
    std[1, 3:] = 0.01, 0.2, 0.01  # the lever arm 1.4 m: 0.2 m is over a tenth
    (car,) = OnlineRigStage.errors(SimpleNamespace(final=SimpleNamespace(extrinsics=E, std=std)), truth)
    assert car["compared_in_plane"] and car["translation_error"] == 0 and car["translation_direction_error_deg"] == 0
    std[1, 4] = 0.01
    (informed,) = OnlineRigStage.errors(SimpleNamespace(final=SimpleNamespace(extrinsics=E, std=std)), truth)
    assert not informed["compared_in_plane"] and informed["translation_error"] == 1.0
    a, b = E[1, :3, 3], truth[1, :3, 3]
    expected = np.degrees(np.arccos(a @ b / np.linalg.norm(a) / np.linalg.norm(b)))
    assert informed["translation_direction_error_deg"] == pytest.approx(expected)
    # on a planar drive the ground's normal is left out too, however well pinned, and its error said apart
    (planar,) = OnlineRigStage.errors(
        SimpleNamespace(final=SimpleNamespace(extrinsics=E, std=std)), truth, np.eye(3)[1:2]
    )
    assert planar["compared_in_plane"] and planar["translation_error"] == 0 and planar["height_error"] == 1.0


@pytest.mark.parametrize("noise", [0.0, 0.05])
def test_a_change_found_with_the_trajectory_held_says_so(noise, tmp_path):
    """A change warning says the trajectory's poses were held as exact (its rotation error would read as a move)
    where its noise was given as 0, and not where the windows solved the poses."""
    image = tmp_path / "a.png"
    cv2.imwrite(str(image), np.zeros((4, 4), np.uint8))
    cameras = [SimpleNamespace(images=[image]), SimpleNamespace(images=[image])]
    sequence = SimpleNamespace(cameras=cameras, names=["cam0", "cam1"], times=None, pairing=None)
    stream = OnlineRigStage(sequence, _trajectory(np.zeros(1)), OnlineRigOptions(metric_noise=noise))
    state = SimpleNamespace(changes=[(1, Change(40, 44, 1.0, 0.05))])
    stream.estimator = SimpleNamespace(update=lambda t, images, pose, rotations: state, keyframe_next=True)
    stream(0, SimpleNamespace(rotation=torch.eye(3, dtype=torch.float64)[None, None]))
    [said] = stream.warnings
    assert said.startswith("on-line rig estimator: cam1: its extrinsic changed at frame 40 (noticed at frame 44)")
    assert ("--metric-noise" in said) == (noise == 0.0), said


def test_the_extrinsics_the_adjustment_is_checked_against_are_those_the_estimator_placed_and_found_steady():
    """Of four cameras, the one placed with a tight rotation is kept; one never placed (NaN 1-sigma), one whose
    rotation 1-sigma is 2 deg, and one that moved mid-run are not (NaN rows)."""
    E = np.tile(np.eye(4), (5, 1, 1))
    E[1:, :3, 3] = np.arange(12.0).reshape(4, 3)
    std = np.zeros((5, 6))
    std[1:, :3] = np.radians(0.1)
    std[2] = np.nan
    std[3, 1] = np.radians(2.0)
    final = SimpleNamespace(extrinsics=E, std=std)
    states = [SimpleNamespace(changes=[(4, object())]), SimpleNamespace(changes=[])]
    out = OnlineRigStage.steady_extrinsics(SimpleNamespace(final=final, states=states))
    assert np.array_equal(out[:2], E[:2]) and np.isnan(out[2:]).all()


def test_an_estimate_the_window_did_not_determine_is_not_to_be_reported():
    """Of five cameras on a 1 m lever arm, the one with tight 1-sigmas is reportable, and so are those whose
    translation 1-sigma is 0.5 m on one or two axes (flagged when reported); one still waiting and one whose
    rotation 1-sigma is 2 deg are not, each with its reason, nor one three quarters of whose keyframes since its
    release did not register."""
    E = np.tile(np.eye(4), (6, 1, 1))
    E[1:, :3, 3] = [1.0, 0.0, 0.0]
    std = np.zeros((6, 6))
    std[1:, :3], std[1:, 3:] = np.radians(0.1), 0.02
    std[2] = np.nan
    std[3, 1] = np.radians(2.0)
    std[4, 3:5] = 0.5
    std[5, 4] = 0.5
    cameras = [CameraState(k, ExtrinsicTrack(), waiting=k == 2, tried=10, registered=9) for k in range(6)]
    stream = SimpleNamespace(
        sequence=SimpleNamespace(cameras=[None] * 6),
        final=SimpleNamespace(extrinsics=E, std=std),
        estimator=SimpleNamespace(cameras=cameras, release_std=(0.5, 0.1)),
    )
    out = OnlineRigStage.undetermined(stream)
    assert sorted(out) == [2, 3], out
    assert "never determined" in out[2] and "2.00 deg" in out[3]
    stream.estimator.cameras[5].registered = 4  # 6 of camera 5's 10 since its release unregistered: still reported
    assert sorted(OnlineRigStage.undetermined(stream)) == [2, 3]
    stream.estimator.cameras[5].registered = 2  # 8 of 10: withheld
    assert sorted(OnlineRigStage.undetermined(stream)) == [2, 3, 5]
    assert "8 of its 10 keyframes since its release did not register" in OnlineRigStage.undetermined(stream)[5]


@pytest.mark.parametrize("by_drift", [True, False])
def test_a_camera_waiting_after_its_change_is_reported_where_its_estimate_is_determined(by_drift):
    """After a change a camera waits until a window determines it again. Restarted by the drift test, its track holds
    the window estimate that found the move, with that window's covariance (0.1 deg, 2 cm): reported. Restarted by
    the split test, its track is uninformed: not reported, the reason naming the change's frame."""
    window = np.diag([np.radians(0.1)] * 3 + [0.02] * 3) ** 2
    track = ExtrinsicTrack()
    track.fuse(np.eye(4), window)
    track.candidate = np.eye(4)
    cam = CameraState(1, track, waiting=False)
    cam.restart(Change(150, 158, 2.0, 0.05), np.eye(4), SimpleNamespace(forget=lambda k, frame: None))
    if by_drift:  # as OnlineRigEstimator._adjust does after the drift test's restart
        track.fuse(np.eye(4), window)
    variance = np.diag(track.covariance)
    std = np.where(variance < UNINFORMED / 10, np.sqrt(variance), np.inf)
    stream = SimpleNamespace(
        sequence=SimpleNamespace(cameras=[None] * 2),
        final=SimpleNamespace(extrinsics=np.tile(np.eye(4), (2, 1, 1)), std=np.stack([np.zeros(6), std])),
        estimator=SimpleNamespace(cameras=[CameraState.reference(ExtrinsicTrack()), cam], release_std=(0.5, 0.1)),
    )
    out = OnlineRigStage.undetermined(stream)
    assert cam.waiting
    if by_drift:
        assert out == {}
    else:
        assert list(out) == [1] and "since its change at frame 150" in out[1]


def test_the_trace_and_its_csv_give_each_cameras_phase(tmp_path):
    """The trace's ``rig_phase`` holds each camera's phase code from the keyframe that set it on (NaN before the
    first), and the trace's CSV writes it as a column of its own."""
    E, std, chi2 = np.tile(np.eye(4), (3, 1, 1)), np.zeros((3, 6)), np.zeros(3)
    states = [
        SimpleNamespace(frame=f, extrinsics=E, std=std, chi2=chi2, changes=[], phases=["reference", *phases])
        for f, phases in ((2, ["waiting", "waiting"]), (4, ["tracking", "disagreeing"]), (6, ["candidate", "tracking"]))
    ]
    stream = SimpleNamespace(sequence=SimpleNamespace(cameras=[None] * 3), states=states)
    phase = OnlineRigStage.trace(stream, 8)["rig_phase"]
    assert np.isnan(phase[:2]).all()
    np.testing.assert_array_equal(phase[2:], [[1, 1], [1, 1], [2, 3], [2, 3], [4, 2], [4, 2]])
    trace = {"frame": np.arange(8), "time": np.arange(8) / 10, "quaternion": np.zeros((8, 2, 4)),
             "rotation_singular_values": np.zeros((8, 2, 3)), **OnlineRigStage.trace(stream, 8)}  # fmt: skip
    run = SimpleNamespace(trace=trace)
    run.trace_table = lambda: CalibrationRun.trace_table(run)
    CalibrationRun.write_trace(run, tmp_path / "trace.csv")
    table = np.genfromtxt(tmp_path / "trace.csv", delimiter=",", names=True)
    assert "rig_phase" in table.dtype.names
    np.testing.assert_array_equal(table["rig_phase"][table["frame"] == 4], [2, 3])  # cameras 1 and 2
