"""The classical VO against the renderer's ground truth: rotations, directions, consistent scale, degenerate
motion flagged (never NaN), conventions, and bad input."""

import cv2
import numpy as np
import pytest
import torch
from frontend_scenes import render_poses

from ocalib.errors import InputError
from ocalib.eval.pose_metrics import frame_motions, step_errors
from ocalib.frontend.opencv import OpenCVFrontEnd
from ocalib.frontend.opencv_vo import OpenCVOdometry, run_opencv_vo
from ocalib.geometry.se3 import rotation_angle_deg
from ocalib.synth import preset


def _turn(yaw_deg: float = 0.0, forward: float = 0.0) -> np.ndarray:
    """A camera-frame motion: rotation about the camera's y axis, then a step along its z axis."""
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.array([0.0, np.radians(yaw_deg), 0.0]))[0]
    T[2, 3] = forward
    return T


@pytest.mark.parametrize("cam", [0, 1])
def test_handheld_rotations_and_directions_match_ground_truth(handheld, cam):
    K = handheld.rig.cameras[cam].K
    poses, flags = run_opencv_vo(handheld.images[cam], K)  # torch (3, H, W) float frames
    gt = handheld.poses[cam].numpy()
    assert poses.shape == gt.shape and np.isfinite(poses).all()
    assert not flags["degenerate"][1:].any()
    err = step_errors(poses, gt, ~flags["degenerate"])
    motion = np.median(rotation_angle_deg(frame_motions(gt)[:, :3, :3]))  # ~1.7 deg a frame
    assert np.median(err["rotation_deg"]) < 0.1 * motion and err["rotation_deg"].max() < 0.5 * motion
    assert np.median(err["direction_deg"]) < 8 and err["direction_deg"].max() < 30
    assert err["scale_cv"] < 0.2


def test_step_is_the_motion_from_the_previous_frame_and_pose_chains_it(handheld):
    vo = OpenCVOdometry(handheld.rig.cameras[0].K)
    chain = np.eye(4)
    for n, image in enumerate(handheld.images[0, :6]):
        T = vo.step(image.permute(1, 2, 0).numpy())  # numpy (H, W, 3) float
        if n == 0:
            np.testing.assert_array_equal(T, np.eye(4))
        chain = chain @ T
        np.testing.assert_allclose(vo.pose, chain, atol=1e-12)
        assert vo.status.frame == n
    gt = handheld.poses[0].numpy()
    gt_step = np.linalg.inv(gt[4]) @ gt[5]  # T_prev_cur: p_prev = T p_cur
    cos = T[:3, 3] @ gt_step[:3, 3] / np.linalg.norm(T[:3, 3]) / np.linalg.norm(gt_step[:3, 3])
    assert cos > 0.9  # not the inverse motion


def test_torch_channel_first_and_numpy_channel_last_agree(handheld):
    frames = handheld.images[1, :5]
    a, _ = run_opencv_vo(frames, handheld.rig.cameras[1].K)
    b, _ = run_opencv_vo([(f.permute(1, 2, 0).numpy() * 255 + 0.5).astype(np.uint8) for f in frames],
                         handheld.rig.cameras[1].K)  # fmt: skip
    np.testing.assert_allclose(a, b, atol=1e-9)


@pytest.mark.parametrize("motion", ["static", "rotation"])
def test_static_and_rotating_camera_are_flagged_rotation_only(street_pose, motion):
    K = preset("front-left").cameras[0].K(128, 416)
    yaw = 0.0 if motion == "static" else 1.5
    poses = np.stack([street_pose @ _turn(yaw * i) for i in range(6)])
    est, flags = run_opencv_vo(render_poses(poses, K), K)
    assert np.isfinite(est).all()
    assert flags["degenerate"].all() and set(flags["reason"][1:]) == {"low parallax"}
    steps = frame_motions(est)
    np.testing.assert_array_equal(steps[:, :3, 3], 0.0)  # rotation only, no invented translation
    assert step_errors(est, poses)["rotation_deg"].max() < 0.1


def test_straight_segment_has_one_scale(street_pose):
    K = preset("front-left").cameras[0].K(128, 416)
    poses = np.stack([street_pose @ _turn(forward=0.5 * i) for i in range(14)])
    est, flags = run_opencv_vo(render_poses(poses, K), K)
    assert not flags["degenerate"][1:].any()
    lengths = np.linalg.norm(frame_motions(est)[:, :3, 3], axis=1)
    assert lengths[0] == pytest.approx(1.0)  # the first moving pair sets the unit
    assert lengths.std() / lengths.mean() < 0.05  # true lengths are all equal
    assert abs(lengths[-3:].mean() / lengths[:3].mean() - 1) < 0.1  # no drift
    directions = frame_motions(est)[:, :3, 3] / lengths[:, None]
    assert np.degrees(np.arccos(directions[:, 2])).max() < 5  # straight ahead (camera z)


@pytest.fixture(scope="module")
def blocked(street_pose):
    """A steady turn (1 deg a frame) whose view is blocked on frames 6 and 7 (uniform grey: nothing to track):
    K, poses (12, 4, 4), the clear images and the blocked ones (12, H, W, 3) uint8."""
    K = preset("front-left").cameras[0].K(128, 416)
    poses = np.stack([street_pose @ _turn(1.0 * i, 0.5 * i) for i in range(12)])
    clear = render_poses(poses, K)
    images = clear.copy()
    images[6:8] = 128
    return K, poses, clear, images


def test_lost_frames_repeat_the_last_step(blocked):
    """A view blocked for two frames (no track survives) gives the last step again, flagged, instead of a rotation
    fitted to the few tracks left; the tracks start again after it."""
    K, poses, _, images = blocked
    est, flags = run_opencv_vo(images, K)
    lost = flags["reason"] == "too few tracks"
    assert lost[6:8].all() and flags["degenerate"][lost].all() and not lost[:6].any()
    steps = frame_motions(est)
    np.testing.assert_allclose(steps[5:7], np.broadcast_to(steps[4], (2, 4, 4)), atol=1e-12)  # frames 6, 7
    err = step_errors(est, poses)["rotation_deg"]
    assert err.max() < 0.25  # a rotation fitted to no tracks would be off by the turn, 1 deg


def test_the_front_end_reports_each_cameras_lost_frames(blocked):
    """Through ``calibrate``'s front end: the lost frames counted per camera, and a warning for the camera that lost
    them."""
    K, _, clear, images = blocked
    front_end = OpenCVFrontEnd(np.stack([K, K]))
    for pair in zip(clear, images):
        front_end([cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) for image in pair])
    settings, warnings = front_end.report(["clear", "blocked"], len(clear), None)
    assert settings == {"lost_frames": {"clear": 0, "blocked": 3}}  # 6, 7 and 8 (nothing to follow from 7 yet)
    [said] = warnings
    assert said.startswith("blocked: the OpenCV front end lost its tracks on 3 of 12 frames")


def test_the_front_end_steps_its_cameras_as_each_camera_alone(blocked):
    """The front end steps the cameras of a frame on threads: each camera's motions are those of its odometry run
    alone, frame by frame, to the bit."""
    K, _, clear, images = blocked
    grey = [[cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) for image in pair] for pair in zip(clear, images)]
    front_end = OpenCVFrontEnd(np.stack([K, K]))
    together = np.concatenate([front_end(pair)[0].numpy()[None] for pair in grey])  # (T, 2, 4, 4)
    for cam in range(2):
        alone = OpenCVOdometry(K)
        np.testing.assert_array_equal(together[:, cam], np.stack([alone.step(pair[cam]) for pair in grey]))


def test_a_bad_frame_of_one_camera_is_an_input_error_through_the_front_end():
    rng = np.random.default_rng(0)
    K = np.array([[50.0, 0, 31.5], [0, 50.0, 23.5], [0, 0, 1]])
    front_end = OpenCVFrontEnd(np.stack([K, K]))
    front_end([rng.integers(0, 255, (48, 64), dtype=np.uint8) for _ in range(2)])
    with pytest.raises(InputError, match="frame 1: image size"):
        front_end([rng.integers(0, 255, (48, 64), dtype=np.uint8), rng.integers(0, 255, (40, 64), dtype=np.uint8)])


def test_bad_intrinsics_and_options_are_input_errors():
    for K in (np.eye(2), np.zeros((3, 4)), np.diag([0.0, 1.0, 1.0]), np.full((3, 3), np.nan)):
        with pytest.raises(InputError, match="intrinsics K"):
            OpenCVOdometry(K)
    with pytest.raises(InputError, match="unknown VO option"):
        OpenCVOdometry(np.eye(3), bogus=1)


def test_bad_frames_are_input_errors_naming_the_frame():
    rng = np.random.default_rng(0)
    vo = OpenCVOdometry(np.array([[50.0, 0, 31.5], [0, 50.0, 23.5], [0, 0, 1]]))
    vo.step(rng.integers(0, 255, (48, 64), dtype=np.uint8))
    vo.step(rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))  # colour is fine
    with pytest.raises(InputError, match="frame 2: image size"):
        vo.step(rng.integers(0, 255, (48, 63), dtype=np.uint8))
    with pytest.raises(InputError, match="frame 2: float image"):
        vo.step(np.full((48, 64), 2.0))
    with pytest.raises(InputError, match="frame 2: expected an image"):
        vo.step(np.zeros((48, 64, 4), np.uint8))
    with pytest.raises(InputError, match="frame 2: expected uint8"):
        vo.step(np.zeros((48, 64), np.int32))
    vo.step(torch.rand(3, 48, 64))  # frame 2, channel-first tensor
    assert vo.status.frame == 2 and np.isfinite(vo.pose).all()


def test_run_names_the_unreadable_file(tmp_path):
    good = tmp_path / "000000.png"
    cv2.imwrite(str(good), np.zeros((32, 32), np.uint8))
    bad = tmp_path / "000001.png"
    bad.write_text("not an image")
    with pytest.raises(InputError, match="000001.png"):
        run_opencv_vo([good, bad], np.eye(3))
    small = tmp_path / "000002.png"
    cv2.imwrite(str(small), np.zeros((32, 30), np.uint8))
    with pytest.raises(InputError, match=r"000002.png: frame 1: image size"):
        run_opencv_vo([good, small], np.eye(3))
    with pytest.raises(InputError, match="empty"):
        run_opencv_vo([], np.eye(3))
