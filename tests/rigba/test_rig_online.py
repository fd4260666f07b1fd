"""The on-line rig estimator: the window adjustment recovers an extrinsic from exact observations, the change
test separates a step from noise, and on a rendered rig the estimator follows the extrinsic, notices a knocked
camera at the right frame, keeps its state bounded, and says so where a camera registers nothing."""

from dataclasses import replace
from types import SimpleNamespace

import cv2
import numpy as np
import pycolmap
import pytest
import torch
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from ocalib.calib.drivers.change import Change
from ocalib.data.distortion import Distortion
from ocalib.data.layout import open_sequence
from ocalib.geometry.se3 import innovation, perturbed, rotation_angle_deg
from ocalib.rigba.camera_state import Phase
from ocalib.rigba.change import ExtrinsicTrack, information, reaches, relative_information
from ocalib.rigba.colmap import to_matrix
from ocalib.rigba.features import Features
from ocalib.rigba.online import OnlineRigEstimator, OnlineRigOptions
from ocalib.rigba.stream import OnlineRigStage
from ocalib.rigba.window import Keyframe, adjust_window, split_statistic
from ocalib.sim.trajectory import off_trajectory
from ocalib.synth import preset
from ocalib.synth.presets import knocked

K = np.array([[240.0, 0, 207.5], [0, 245.0, 63.5], [0, 0, 1]])


def _mounting(rotation_deg, position) -> np.ndarray:
    E = np.eye(4)
    E[:3, :3] = Rotation.from_euler("xyz", rotation_deg, degrees=True).as_matrix()
    E[:3, 3] = position
    return E


def _rig_pose(i: float) -> np.ndarray:
    """The test rig's pose at keyframe ``i`` (fractional: between keyframes), camera-to-world (4, 4)."""
    return _mounting(np.degrees([0.02 * i, 0.05 * i, 0.01 * i]), [0.1 * i, 0.02 * i, 0.2 * i])


def _level_turn(i: float) -> np.ndarray:
    """A rig turning on level ground from the origin (10 m radius, 2.3 deg a keyframe about the vertical y axis):
    its positions lie in the plane y = 0, through the origin. Camera-to-world (4, 4)."""
    angle = 0.04 * i
    return _mounting([0, np.degrees(angle), 0], [10 * np.sin(angle), 0.0, 10 * (1 - np.cos(angle))])


def _window(rng, truth, moved=None, at: int = 8, sigma_px: float = 0.3, late: float = 0.0, path=_rig_pose):
    """12 keyframes of a rig (extrinsics ``truth`` (C, 4, 4)) along ``path`` (keyframe -> pose), 150 points in front
    of each camera at the first, seen only by it, observed with ``sigma_px`` noise; camera 1 at ``moved`` from
    keyframe ``at`` on, capturing ``late`` keyframes after camera 0 (each keyframe holds both capture poses).
    -> keyframes, points (their positions off by 5 cm)."""
    poses = [path(i) for i in range(12)]
    points, keyframes = {}, []
    world = []
    for k in range(len(truth)):
        depth, uv = rng.uniform(3, 8, 150), rng.uniform([0, 0], [416, 128], (150, 2))
        rays = (np.linalg.inv(K) @ np.c_[uv, np.ones(150)].T).T * depth[:, None]
        cam = poses[0] @ truth[k]
        world.append(rays @ cam[:3, :3].T + cam[:3, 3])
        points.update({150 * k + j: X + rng.normal(0, 0.05, 3) for j, X in enumerate(world[k])})
    for i, pose in enumerate(poses):
        features, ids = [], []
        captured = np.stack([pose, path(i + late)] + [pose] * (len(truth) - 2))
        for k in range(len(truth)):
            mounting = moved if (k == 1 and moved is not None and i >= at) else truth[k]
            T = np.linalg.inv(captured[k] @ mounting)
            p = world[k] @ T[:3, :3].T + T[:3, 3]
            uv = p @ K.T
            xy = uv[:, :2] / uv[:, 2:] + rng.normal(0, sigma_px, (150, 2))
            inside = (p[:, 2] > 0) & (xy >= 0).all(1) & (xy < [416, 128]).all(1)
            features.append(Features(xy, np.zeros((150, 128), np.float32)))
            ids.append(np.where(inside, 150 * k + np.arange(150), -1))
        keyframes.append(Keyframe(i, captured, features, ids, pose.copy()))
    return keyframes, points


def _tilted(keyframes, at: int, degrees: float) -> None:
    """Turn the rig's held poses from keyframe ``at`` on by ``degrees`` about the world's z axis, as a real
    trajectory's rotation is off (GNSS/INS, odometry); the images and the positions stay true."""
    tilt = Rotation.from_euler("z", degrees, degrees=True).as_matrix()
    for kf in keyframes[at:]:
        kf.poses[:, :3, :3] = tilt @ kf.poses[:, :3, :3]


def test_the_window_recovers_an_extrinsic_from_exact_observations():
    rng = np.random.default_rng(1)
    truth = np.stack([np.eye(4), _mounting([0, 120, 0], [0.12, 0.0, -0.05])])
    keyframes, points = _window(rng, truth)
    start = truth.copy()
    start[1, :3, 3] = 0.0
    start[1, :3, :3] = Rotation.from_rotvec(np.radians([0.3, 0.2, -0.2])).as_matrix() @ truth[1, :3, :3]
    for _ in range(3):  # as the stream solves it again at every keyframe, from the last solution
        result = adjust_window(keyframes, points, start, np.stack([K, K]), [(128, 416)] * 2)
    assert result.reprojection_px < 0.6
    assert float(rotation_angle_deg(start[1, :3, :3].T @ truth[1, :3, :3])) < 0.2
    std = np.sqrt(np.diag(result.uncertainty[0].covariance))
    error = start[1, :3, 3] - truth[1, :3, 3]
    assert np.all(np.abs(error) < 3 * std[3:]), (error, std)  # the reported 1-sigma covers the error
    assert np.linalg.norm(error) < 0.25 * np.linalg.norm(truth[1, :3, 3])


def test_a_window_that_holds_the_poses_counts_them_given():
    """The same window with the rig's poses held (an exact trajectory) and solved (a noise stated): held, every
    variance of the extrinsic is smaller (the poses carry no uncertainty into it), and its 1-sigma still covers its
    error (3-sigma on every axis)."""
    truth = np.stack([np.eye(4), _mounting([0, 120, 0], [0.12, 0.0, -0.05])])
    start = truth.copy()
    start[1, :3, 3] = 0.0
    start[1, :3, :3] = Rotation.from_rotvec(np.radians([0.3, 0.2, -0.2])).as_matrix() @ truth[1, :3, :3]
    out = {}
    for name, noise in (("held", None), ("solved", 0.01)):
        keyframes, points = _window(np.random.default_rng(1), truth)
        E = start.copy()
        for _ in range(3):
            result = adjust_window(keyframes, points, E, np.stack([K, K]), [(128, 416)] * 2, prior_noise=noise)
        out[name] = E[1], result.uncertainty[0].covariance
    (E, held), (_, solved) = out["held"], out["solved"]
    assert np.all(np.diag(held) < np.diag(solved)), (np.diag(held), np.diag(solved))
    error = innovation(truth[1], E)
    assert np.all(np.abs(error) < 3 * np.sqrt(np.diag(held))), (error, np.sqrt(np.diag(held)))


def test_a_window_that_solves_the_poses_counts_the_stated_noise_of_their_positions():
    """The rig's poses solved with camera 0's positions as priors: the tighter their stated noise, the better the
    window states the lever arm (the priors carry the scale into it), and its 3-sigma still covers the error."""
    truth = np.stack([np.eye(4), _mounting([0, 120, 0], [0.12, 0.0, -0.05])])
    variances = []
    for noise in (0.05, 0.001):
        keyframes, points = _window(np.random.default_rng(1), truth)
        E = truth.copy()
        for _ in range(3):
            result = adjust_window(keyframes, points, E, np.stack([K, K]), [(128, 416)] * 2, prior_noise=noise)
        covariance = result.uncertainty[0].covariance
        variances.append(np.diag(covariance)[3:])
        error = innovation(truth[1], E[1])
        assert np.all(np.abs(error) < 3 * np.sqrt(np.diag(covariance))), (error, np.sqrt(np.diag(covariance)))
    loose, tight = variances
    assert np.all(tight < loose), (loose, tight)


def test_a_held_camera_keeps_its_extrinsic_while_the_others_are_adjusted():
    """``held``: camera 1's extrinsic stays where it was (the estimator holds a camera whose observations span too
    few keyframes); the same window without it moves camera 1 towards the truth."""
    truth = np.stack([np.eye(4), _mounting([0, 120, 0], [0.12, 0.0, -0.05])])
    start = truth.copy()
    start[1, :3, 3] = 0.0
    held, free = start.copy(), start.copy()
    adjust_window(*_window(np.random.default_rng(2), truth), held, np.stack([K, K]), [(128, 416)] * 2, frozenset({1}))
    np.testing.assert_allclose(held, start, atol=1e-12)
    adjust_window(*_window(np.random.default_rng(2), truth), free, np.stack([K, K]), [(128, 416)] * 2)
    assert np.linalg.norm(free[1, :3, 3] - truth[1, :3, 3]) < 0.5 * np.linalg.norm(truth[1, :3, 3])


def test_a_camera_solved_apart_neither_bends_the_others_nor_inflates_their_uncertainty():
    """Camera 2 waits 2 deg and its whole 1.1 m lever arm off while the window solves the rig's poses. Solved apart,
    camera 1 comes out as from the same window without camera 2's observations (the reference), near its truth,
    with about the variance it has where camera 2 is held at its truth (the waiting camera's misfit is not taken for
    noise); camera 2 stays where it is held, and the window's try of it free (``WindowResult.trials``) is nearer its
    truth. Held in the joint adjustment instead, its misfit bends the rig's poses and camera 1 with them."""
    truth = np.stack([np.eye(4), _mounting([0, 120, 0], [0.12, 0.0, -0.05]), _mounting([0, -150, 0], [-0.4, 0, -1.0])])
    Ks, sizes = np.stack([K] * 3), [(128, 416)] * 3
    wrong = truth.copy()
    wrong[2, :3, :3] = Rotation.from_euler("y", 2, degrees=True).as_matrix() @ truth[2, :3, :3]
    wrong[2, :3, 3] = 0.0

    def adjusted(start, apart=frozenset({2}), without_camera_2=False):
        keyframes, points = _window(np.random.default_rng(4), truth)
        for kf in keyframes if without_camera_2 else ():
            kf.point_ids[2][:] = -1
        E = start.copy()
        return E, adjust_window(keyframes, points, E, Ks, sizes, frozenset({2}), 0.01, apart)

    held, result = adjusted(wrong)
    reference, at_truth = adjusted(wrong, without_camera_2=True)[0], adjusted(truth)[1]
    np.testing.assert_allclose(held[1], reference[1], atol=1e-9)
    assert float(rotation_angle_deg(held[1, :3, :3].T @ truth[1, :3, :3])) < 0.3
    assert np.linalg.norm(held[1, :3, 3] - truth[1, :3, 3]) < 0.05
    ratio = np.diag(result.uncertainty[0].covariance) / np.diag(at_truth.uncertainty[0].covariance)
    assert np.all(ratio < 1.5), ratio  # 8x were the misfit taken for noise; the rest: camera 2's outliers dropped
    np.testing.assert_allclose(held[2], wrong[2], atol=1e-12)
    tried, placed = result.trials[2]
    assert float(rotation_angle_deg(tried[:3, :3].T @ truth[2, :3, :3])) < 0.5
    assert np.linalg.norm(tried[:3, 3] - truth[2, :3, 3]) < 0.5 * np.linalg.norm(truth[2, :3, 3])
    assert set(placed) <= set(range(300, 450)) and len(placed) > 100  # its own points, as the try places them
    joint, _ = adjusted(wrong, apart=frozenset())
    assert float(rotation_angle_deg(joint[1, :3, :3].T @ truth[1, :3, :3])) > 2.0


def test_a_camera_captured_late_is_adjusted_at_its_own_capture_pose():
    """Camera 1 captures half a keyframe after camera 0 (the rig moves 11 cm, about the lever arm, in between): the
    window placing it at its own capture pose recovers the extrinsic; placed at camera 0's, it is a lever arm off."""
    truth = np.stack([np.eye(4), _mounting([0, 120, 0], [0.12, 0.0, -0.05])])
    start = truth.copy()
    start[1, :3, 3] = 0.0
    errors = []
    for own_pose in (True, False):
        keyframes, points = _window(np.random.default_rng(3), truth, late=0.5)
        for kf in keyframes if not own_pose else ():
            kf.poses[1] = kf.poses[0]
        E = start.copy()
        for _ in range(3):
            adjust_window(keyframes, points, E, np.stack([K, K]), [(128, 416)] * 2)
        errors.append(np.linalg.norm(E[1, :3, 3] - truth[1, :3, 3]) / np.linalg.norm(truth[1, :3, 3]))
    assert errors[0] < 0.3 and errors[1] > 1.0, errors


def test_the_split_window_tells_a_moved_camera_from_a_steady_one():
    """The likelihood ratio of a second extrinsic from keyframe 8 on: near chi-square(6) on a steady camera (mean 6
    over seeds), thousands where it turned by 1 deg; the window given is left as it was."""
    truth = np.stack([np.eye(4), _mounting([0, 120, 0], [0.12, 0.0, -0.05])])
    moved = _mounting([0, 121, 0], [0.12, 0.0, -0.05])
    Ks, sizes = np.stack([K, K]), [(128, 416)] * 2
    steady = []
    for seed in range(8):
        rng = np.random.default_rng(seed)
        keyframes, points = _window(rng, truth)
        adjust_window(keyframes, points, truth.copy(), Ks, sizes)
        before = {p: x.copy() for p, x in points.items()}
        steady.append(split_statistic(keyframes, points, truth.copy(), Ks, sizes, 1, 8).statistic)
        assert all(np.array_equal(points[p], x) for p, x in before.items())
    assert max(steady) < chi2.ppf(1 - 1e-4, 6) and 3.0 < np.mean(steady) < 10.0, steady
    keyframes, points = _window(np.random.default_rng(0), truth, moved)
    extrinsics = truth.copy()
    adjust_window(keyframes, points, extrinsics, Ks, sizes)
    split = split_statistic(keyframes, points, extrinsics, Ks, sizes, 1, 8)
    assert split.statistic > 1000 and 0.7 < split.rotation_deg < 1.3, split  # the step, as the window measures it
    assert np.isnan(split_statistic(keyframes, points, extrinsics, Ks, sizes, 1, 12).statistic)  # nothing after


def test_a_trajectory_whose_rotation_is_off_is_not_read_as_a_moved_camera_where_its_noise_is_stated():
    """The rig's held rotation off by 0.3 deg from keyframe 8 on (1.3 px at this focal length; a real trajectory's
    rotation is off by tenths of a degree): held, the split test reads camera 1 as moved; with the trajectory's noise
    stated the window solves the rig's poses (its positions on a line, which COLMAP's alignment to the priors rejects:
    the window is anchored at two keyframes instead), and the ratio stays near
    chi-square(6) (mean 6), the extrinsic and the rig's turns as from the true trajectory, while a 1 deg turn of the
    camera stays in the thousands."""
    truth = np.stack([np.eye(4), _mounting([0, 120, 0], [0.12, 0.0, -0.05])])
    Ks, sizes = np.stack([K, K]), [(128, 416)] * 2

    def solved(seed, tilt, noise, moved=None):
        keyframes, points = _window(np.random.default_rng(seed), truth, moved)
        _tilted(keyframes, 8, tilt)
        extrinsics = truth.copy()
        adjust_window(keyframes, points, extrinsics, Ks, sizes, prior_noise=noise)
        turns = [kf.poses[0, :3, :3].T @ keyframes[0].poses[0, :3, :3] for kf in keyframes]
        return split_statistic(keyframes, points, extrinsics, Ks, sizes, 1, 8, noise), extrinsics[1], turns

    held, free = [], []
    for seed in range(6):
        held.append(solved(seed, 0.3, None)[0].statistic)
        split, E, turns = solved(seed, 0.3, 0.01)
        _, E_true, turns_true = solved(seed, 0.0, 0.01)  # the reference: the same window, the trajectory true
        free.append(split.statistic)
        assert float(rotation_angle_deg(E[:3, :3].T @ E_true[:3, :3])) < 0.01
        assert max(float(rotation_angle_deg(a.T @ b)) for a, b in zip(turns, turns_true)) < 0.01
    assert min(held) > 500 and max(free) < chi2.ppf(1 - 1e-4, 6) and np.mean(free) < 10.0, (held, free)
    split = solved(0, 0.3, 0.01, moved=_mounting([0, 121, 0], [0.12, 0.0, -0.05]))[0]
    assert split.statistic > 1000 and 0.7 < split.rotation_deg < 1.3, split


def _resected(rng, pose, mounting, sigma_px=0.5, n=120):
    """A keyframe of a camera mounted at ``mounting`` on a rig at ``pose``: keypoints (n, 2) of points (n, 3) 3-8 m
    in front, with ``sigma_px`` of noise, and the camera's cam_from_world resected from them by COLMAP."""
    cam_from_world = np.linalg.inv(pose @ mounting)
    uv = rng.uniform([0, 0], [416, 128], (n, 2))
    rays = (np.linalg.inv(K) @ np.c_[uv, np.ones(n)].T).T * rng.uniform(3, 8, (n, 1))
    world_from_cam = np.linalg.inv(cam_from_world)
    xyz = rays @ world_from_cam[:3, :3].T + world_from_cam[:3, 3]
    xy = uv + rng.normal(0, sigma_px, (n, 2))
    camera = pycolmap.Camera(model="PINHOLE", width=416, height=128, params=[K[0, 0], K[1, 1], K[0, 2] + 0.5,
                                                                          K[1, 2] + 0.5])  # fmt: skip
    result = pycolmap.estimate_and_refine_absolute_pose(xy + 0.5, xyz, camera)
    return xy, xyz, to_matrix(result["cam_from_world"])


def test_a_keyframes_information_makes_its_error_a_chi_square_with_six_degrees_of_freedom():
    """With Gaussian pixel noise, the least-squares extrinsic's error ``d`` against the truth weighed by the
    keyframe's information, ``d^T I d``, is chi-square distributed with the pose's 6 degrees of freedom."""
    rng = np.random.default_rng(0)
    mounting = _mounting([0, 90, 0], [0.9, 0, 0])
    statistics = []
    for _ in range(200):
        pose = _mounting(rng.normal(0, 10, 3), rng.normal(0, 2, 3))
        xy, xyz, measured = _resected(rng, pose, mounting)
        extrinsic = np.linalg.inv(pose) @ np.linalg.inv(measured)
        d = innovation(mounting, extrinsic)
        statistics.append(d @ information(xy, xyz, K, pose, extrinsic) @ d)
    assert 5.0 < np.mean(statistics) < 7.0 and 7.0 < np.var(statistics) < 18.0  # chi-square(6): mean 6, variance 12


def test_an_extrinsic_measured_against_camera_0s_resection_has_its_error_chi_square_with_both_uncertainties():
    """Where the rig's pose is camera 0's own resection (the window solves the poses), a keyframe's extrinsic is
    ``inverse(camera 0's pose) @ camera k's``: its error weighed by :func:`relative_information` (camera k's
    information with camera 0's uncertainty added) is chi-square with 6 degrees of freedom; by camera k's alone, it
    is well over (camera 0's error left out)."""
    rng = np.random.default_rng(1)
    mounting = _mounting([0, 90, 0], [0.9, 0, 0])
    both, alone = [], []
    for _ in range(200):
        pose = _mounting(rng.normal(0, 10, 3), rng.normal(0, 2, 3))
        xy0, xyz0, measured0 = _resected(rng, pose, np.eye(4))
        xy, xyz, measured = _resected(rng, pose, mounting)
        rig = np.linalg.inv(measured0)  # camera 0's resected camera-to-world: the rig's pose
        extrinsic = np.linalg.inv(rig) @ np.linalg.inv(measured)
        d = innovation(mounting, extrinsic)
        info = information(xy, xyz, K, rig, extrinsic)
        both.append(d @ relative_information(info, information(xy0, xyz0, K, rig, np.eye(4)), extrinsic) @ d)
        alone.append(d @ info @ d)
    assert 5.0 < np.mean(both) < 7.0 and 7.0 < np.var(both) < 18.0 and np.mean(alone) > 20.0, (
        np.mean(both),
        np.var(both),
        np.mean(alone),
    )


@pytest.mark.parametrize("seed", range(5))
def test_the_change_test_gives_no_alarm_on_a_steady_camera_and_finds_a_step(seed):
    rng = np.random.default_rng(seed)
    before, after = _mounting([0, 90, 0], [0.9, 0, 0]), _mounting([0, 92, 0], [0.95, 0, 0])
    track = ExtrinsicTrack()
    track.fuse(before, np.eye(6) * 1e-4)
    window = before, np.eye(6) * 1e-8
    changes = []
    for t in range(160):
        pose = _mounting(rng.normal(0, 10, 3), rng.normal(0, 2, 3))
        xy, xyz, measured = _resected(rng, pose, before if t < 150 else after)
        extrinsic = np.linalg.inv(pose) @ np.linalg.inv(measured)
        change = track.observe(t, extrinsic, information(xy, xyz, K, pose, extrinsic), window)
        if change is not None:
            track.accept(change)
            window = track.extrinsic, window[1]  # the window restarts from the change's estimate
        changes.append(change)
    assert not any(changes[:150]), "a false alarm"
    found = [c for c in changes if c is not None]
    assert (
        track.changes == found
        and len(found) == 1
        and found[0].frame == 150
        and found[0].detected == 150 + track.persistence - 1
    )
    assert abs(found[0].rotation_change_deg - 2.0) < 0.2 and abs(found[0].translation_change - 0.05) < 0.02
    assert np.degrees(np.linalg.norm(innovation(track.extrinsic, after)[:3])) < 0.2


@pytest.mark.parametrize("seed", range(5))
def test_a_window_that_follows_a_step_is_caught_drifting_from_the_track(seed):
    """Windows whose estimates scatter by their covariance about the mounting: no alarm in 100 steady windows; windows
    that moved with the camera (the keyframes' test then sees nothing) are caught on the second, and the track
    takes the window's estimate."""
    rng = np.random.default_rng(seed)
    before, after = _mounting([0, 90, 0], [0.9, 0, 0]), _mounting([0, 91, 0], [0.92, 0, 0])
    covariance = np.diag([1e-6] * 3 + [1e-4] * 3)  # 0.06 deg, 1 cm
    track = ExtrinsicTrack()
    changes = []
    for t in range(110):
        window = perturbed(before if t < 100 else after, rng.multivariate_normal(np.zeros(6), covariance))
        change = track.drifted(t, window, covariance)
        if change is not None:
            track.accept(change)
        changes.append(change)
        track.fuse(window, covariance)
    assert not any(changes[:100]), "a false alarm"
    found = [c for c in changes if c is not None]
    assert len(found) == 1 and found[0].frame == 100 and found[0].detected == 100 + track.persistence - 1
    assert track.changes == found and abs(found[0].rotation_change_deg - 1.0) < 0.3
    assert np.degrees(np.linalg.norm(innovation(track.extrinsic, after)[:3])) < 0.2


def test_the_keyframes_test_runs_from_the_first_keyframe_after_the_window_determines_the_camera():
    """A camera released just before a knock: the first tested keyframes are tested, with no history of steady
    statistics yet (a knock 4 keyframes after a release was followed by the window unnoticed while the test waited
    for 10 steady ones): a keyframe 2 deg off disagrees at once, the next completes the candidate, and keyframes
    within their noise raise nothing and make the history."""
    rng = np.random.default_rng(0)
    mounting, knocked_mounting = _mounting([0, 90, 0], [0.9, 0, 0]), _mounting([0, 92, 0], [0.9, 0, 0])
    info, window = np.diag([1e6] * 3 + [1e4] * 3), np.diag([1e-6] * 3 + [1e-4] * 3)  # 0.06 deg, 1 cm
    track = ExtrinsicTrack()
    track.fuse(mounting, window)
    reference = mounting, window
    for frame in range(4):
        measured = perturbed(mounting, rng.multivariate_normal(np.zeros(6), np.linalg.inv(info) + window))
        assert track.observe(frame, measured, info, reference) is None and not track.disagrees
    assert track.observe(4, knocked_mounting, info, reference) is None and track.disagrees
    change = track.observe(5, knocked_mounting, info, reference)
    assert change is not None and change.frame == 4 and abs(change.rotation_change_deg - 2.0) < 1e-6


@pytest.fixture(scope="module")
def knocked_rig(render):
    """A hand-held rig, 120 frames at 128x416, camera 1 turned by 2 deg about its y axis at frame 70."""
    cfg = knocked(preset("handheld").with_overrides(frames=120, height=128, width=416, seed=1017), 70)
    return open_sequence(render(cfg, workers=2))


EXACT = OnlineRigOptions(metric_noise=0.0)  # the rendered poses: exact, held


def _run(sequence, frames, options=EXACT, trajectory_error: float = 0.0):
    cams = sequence.cameras
    truth = np.stack([np.linalg.inv(cams[0].T_cam0_cam) @ c.T_cam0_cam for c in cams])
    start = truth.copy()
    start[1, :3, :3] = Rotation.from_rotvec(np.radians([0.3, 0.2, -0.2])).as_matrix() @ truth[1, :3, :3]
    estimator = OnlineRigEstimator(np.stack([c.K for c in cams]), [tuple(c.size) for c in cams], start, options)
    poses = off_trajectory(cams[0].poses, trajectory_error) if trajectory_error else cams[0].poses
    poses = np.linalg.inv(poses[:1]) @ poses
    states = []
    for t in frames:
        images = [cv2.imread(str(c.images[t]), cv2.IMREAD_GRAYSCALE) for c in cams]
        state = estimator.update(t, images, poses[t])
        if state is not None:
            states.append(state)
            assert len(estimator.map.keyframes) <= options.window
    return estimator, states, truth


def test_a_rendered_rig_is_followed_and_its_knocked_camera_noticed(knocked_rig):
    estimator, states, truth = _run(knocked_rig, range(120))
    steady = [s for s in states if s.frame < 70]
    assert not any(s.changes for s in steady)
    before = steady[-1].extrinsics[1]
    assert float(rotation_angle_deg(before[:3, :3].T @ truth[1, :3, :3])) < 0.5
    error, std = before[:3, 3] - truth[1, :3, 3], steady[-1].std[1, 3:]
    assert np.all(np.abs(error) < 3 * std), (error, std)  # the reported 1-sigma covers the error
    assert np.linalg.norm(error) < np.linalg.norm(truth[1, :3, 3])  # within a baseline after 35 keyframes
    changes = [(s.frame, c) for s in states for k, c in s.changes]
    assert len(changes) == 1, changes
    detected, change = changes[0]
    assert 70 <= change.frame <= 74 and detected <= 70 + 30
    assert 1.0 < change.rotation_change_deg < 4.0  # the step, the disagreeing keyframes' mean measurement
    after = np.linalg.inv(knocked_rig.cameras[0].T_cam0_cam) @ knocked_rig.cameras[1].change.T_cam0_cam
    final = states[-1].extrinsics[1]
    assert float(rotation_angle_deg(final[:3, :3].T @ after[:3, :3])) < 0.5
    assert len(estimator.map.points) < 40 * 1024  # the window's points only


def test_a_trajectory_off_as_a_real_one_is_needs_its_noise_stated(knocked_rig):
    """Camera 0's trajectory off as GNSS/INS or odometry is (its rotation by a random walk of 0.05 deg a frame, its
    positions by 1 cm): with its noise stated the window solves the rig's poses with the images, only the knock at
    frame 70 is found, and the extrinsic is within 0.75 deg before and after it; held, the trajectory's error goes
    into the extrinsic: over 1 deg off after the knock, or read as a change that did not happen."""
    after = np.linalg.inv(knocked_rig.cameras[0].T_cam0_cam) @ knocked_rig.cameras[1].change.T_cam0_cam
    errors, changes = {}, {}
    for name, options in (("held", EXACT), ("stated", OnlineRigOptions(metric_noise=0.01))):
        _, states, truth = _run(knocked_rig, range(120), options, trajectory_error=0.05)
        changes[name] = [c.frame for s in states for k, c in s.changes]
        before = [s for s in states if s.frame < 70][-1].extrinsics[1]
        final = states[-1].extrinsics[1]
        errors[name] = [float(rotation_angle_deg(E[:3, :3].T @ T[:3, :3])) for E, T in ((before, truth[1]),
                                                                                        (final, after))]  # fmt: skip
    assert len(changes["stated"]) == 1 and 70 <= changes["stated"][0] <= 74, changes
    assert max(errors["stated"]) < 0.75, errors
    assert any(70 <= f <= 74 for f in changes["held"]), changes
    assert errors["held"][1] > 1.0 or len(changes["held"]) > 1, (errors, changes)


def _assert_followed_the_priors(unmoved, moved):
    """The window's solved positions and extrinsic, ``(positions (F, 3), extrinsic (4, 4))``, with its priors as
    given and moved 0.3 m along x: the positions moved with them, the extrinsic stayed."""
    (before, E_before), (after, E_after) = unmoved, moved
    np.testing.assert_allclose(after - before, np.tile([0.3, 0.0, 0.0], (len(before), 1)), atol=2e-3)
    assert float(rotation_angle_deg(E_after[:3, :3].T @ E_before[:3, :3])) < 0.01
    np.testing.assert_allclose(E_after[:3, 3], E_before[:3, 3], atol=2e-3)


def test_the_windows_solved_poses_take_the_metric_positions_as_priors(knocked_rig):
    """With the trajectory's noise stated, camera 0's metric positions are priors of the poses the window solves
    (COLMAP's pose-prior adjuster): the estimator's window on the rendered rig, given positions 0.3 m off along x,
    ends with its poses 0.3 m off along x and its extrinsic where it was."""
    estimator, _, _ = _run(knocked_rig, range(40), OnlineRigOptions(metric_noise=0.01))
    assert estimator.windows_solved > 0 and estimator.windows_without_priors == 0
    solved = []
    for shift in (0.0, 0.3):
        keyframes = [
            replace(kf, poses=kf.poses.copy(), point_ids=[ids.copy() for ids in kf.point_ids], prior=kf.prior.copy())
            for kf in estimator.map.keyframes
        ]
        for kf in keyframes:
            kf.prior[:3, 3] += [shift, 0.0, 0.0]
        extrinsics = estimator.extrinsics.copy()
        result = adjust_window(keyframes, dict(estimator.map.points), extrinsics, estimator.K, estimator.sizes,
                               prior_noise=0.01)  # fmt: skip
        assert result.priors_used
        solved.append((np.stack([kf.poses[0, :3, 3] for kf in keyframes]), extrinsics[1]))
    _assert_followed_the_priors(*solved)


def test_a_window_turning_on_level_ground_takes_its_priors():
    """Positions in a plane through the origin (a drive on level ground, its trajectory re-referenced to its first
    frame), which COLMAP's Sim(3) estimate rejects as they are: the window takes them as priors all the same (moved
    off the origin), its solved positions follow priors moved 0.3 m and its extrinsic stays where it was."""
    truth = np.stack([np.eye(4), _mounting([0, 120, 0], [0.12, 0.0, -0.05])])
    solved = []
    for shift in (0.0, 0.3):
        keyframes, points = _window(np.random.default_rng(0), truth, path=_level_turn)
        priors = np.stack([kf.prior[:3, 3] for kf in keyframes])
        assert np.abs(priors[:, 1]).max() < 1e-12 and not priors[0].any()
        options = pycolmap.RANSACOptions(max_error=0.03, random_seed=0)
        assert pycolmap.estimate_sim3d_robust(priors, priors, options) is None  # COLMAP alone rejects them
        for kf in keyframes:
            kf.prior[:3, 3] += [shift, 0.0, 0.0]
        extrinsics = truth.copy()
        result = adjust_window(keyframes, points, extrinsics, np.stack([K, K]), [(128, 416)] * 2, prior_noise=0.01)
        assert result.priors_used
        solved.append((np.stack([kf.poses[0, :3, 3] for kf in keyframes]), extrinsics[1]))
    _assert_followed_the_priors(*solved)


def test_a_window_whose_positions_lie_on_a_line_says_it_did_not_take_its_priors():
    """COLMAP's alignment to the position priors rejects positions on a line, and its adjuster then fixes the gauge
    at two keyframes instead: the window says so, and indeed its solved positions do not follow priors moved 0.3 m,
    as they do where it takes them (the tests above)."""
    truth = np.stack([np.eye(4), _mounting([0, 120, 0], [0.12, 0.0, -0.05])])
    solved = []
    for shift in (0.0, 0.3):
        keyframes, points = _window(np.random.default_rng(0), truth)
        for kf in keyframes:
            kf.prior[:3, 3] += [shift, 0.0, 0.0]
        result = adjust_window(keyframes, points, truth.copy(), np.stack([K, K]), [(128, 416)] * 2, prior_noise=0.01)
        assert result.priors_used is False
        solved.append(np.stack([kf.poses[0, :3, 3] for kf in keyframes]))
    np.testing.assert_allclose(solved[1], solved[0], atol=1e-9)
    held = adjust_window(*_window(np.random.default_rng(0), truth), truth.copy(), np.stack([K, K]), [(128, 416)] * 2)
    assert held.priors_used is None  # the poses held: no priors to take


def test_a_candidate_waits_for_four_keyframes_and_its_camera_is_held_meanwhile():
    """A candidate change waits for ``CONFIRM_SPAN`` keyframes from its frame on before the window's split test
    judges it, whatever the keyframes between say; meanwhile the window holds the camera and its new points are
    triangulated where its own resections put it."""
    estimator = OnlineRigEstimator(np.stack([K, K]), [(128, 416)] * 2, np.stack([np.eye(4), np.eye(4)]))
    estimator.cameras[1].candidate = Change(10, 12, 8.0, 1.0)
    estimator.map.keyframes.extend(Keyframe(f, np.tile(np.eye(4), (2, 1, 1)), [], []) for f in (8, 10, 12, 14))
    assert estimator._judge(14) == [] and 1 in estimator.candidates  # 3 keyframes from frame 10 on: it waits
    assert estimator.cameras[1].suspect and not estimator.cameras[1].track.disagrees  # held, whatever they say
    assert estimator.cameras[1].held and estimator.cameras[1].phase is Phase.CANDIDATE
    calls = []
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(estimator, "_confirmed", lambda k, change: calls.append((k, change.frame)) or None)
        estimator.map.keyframes.append(Keyframe(16, np.tile(np.eye(4), (2, 1, 1)), [], []))
        assert estimator._judge(16) == []  # judged: the split test did not confirm it
    assert calls == [(1, 10)] and not estimator.candidates and not estimator.cameras[1].suspect


def test_a_candidate_is_judged_at_the_disagreeing_keyframe_where_the_camera_moved():
    """Camera 1 turned by 1 deg from keyframe 8 of the window; its candidate change was raised by two disagreeing
    keyframes, a stray one at keyframe 3 (a resection misled before the move) and keyframe 8. The window's split
    test is run at each and the change is placed where it finds the move: at keyframe 8, its size the measurement
    from there on, the camera's observations from before it dropped."""
    truth = np.stack([np.eye(4), _mounting([0, 120, 0], [0.12, 0.0, -0.05])])
    moved = _mounting([0, 121, 0], [0.12, 0.0, -0.05])
    keyframes, points = _window(np.random.default_rng(0), truth, moved)
    estimator = OnlineRigEstimator(
        np.stack([K, K]), [(128, 416)] * 2, truth.copy(), OnlineRigOptions(metric_noise=0.01)
    )
    estimator.map.keyframes.extend(keyframes)
    estimator.map.points.update(points)
    track = estimator.cameras[1].track
    track.fuse(truth[1], np.eye(6) * 1e-6)
    stray = _mounting([0, 120.6, 0], [0.12, 0.0, -0.05])
    track.disagreed = [(3, stray, truth[1]), (8, moved, truth[1])]
    change = track.candidate_from(3, 8)
    assert 0.7 < change.rotation_change_deg < 0.9  # the two measurements' mean
    confirmed = estimator._confirmed(1, change)
    assert confirmed is not None and confirmed.frame == 8 and confirmed.detected == 8
    assert 0.95 < confirmed.rotation_change_deg < 1.05, confirmed
    assert all((kf.point_ids[1] < 0).all() for kf in estimator.map.keyframes if kf.frame < 8)


def test_a_candidate_raised_at_the_streams_end_is_reported_unjudged(knocked_rig):
    estimator, states, truth = _run(knocked_rig, range(75))  # the knock at 70: fewer than 4 keyframes after it
    assert not any(s.changes for s in states) and list(estimator.candidates) == [1]
    assert states[0].phases == ["reference", "waiting"] and states[-1].phases == ["reference", "candidate"]
    assert any(s.phases[1] == "tracking" for s in states if s.frame < 70)
    cams = knocked_rig.cameras
    sequence = SimpleNamespace(cameras=cams, names=["cam0", "cam1"], times=None, pairing=None)
    stream = OnlineRigStage(sequence, np.linalg.inv(cams[0].poses[:1]) @ cams[0].poses[:75])
    stream.estimator, stream.states = estimator, states
    [entry] = stream.result_json()["unjudged_changes"]
    assert entry["camera"] == "cam1" and 70 <= entry["frame"] <= 74 and entry["rotation_change_deg"] > 1.0
    head = SimpleNamespace(planar_axis=torch.zeros(1, 1, 3), planar_motion=torch.zeros(1, 1, dtype=torch.bool))
    stream.attach(SimpleNamespace(run=SimpleNamespace(trace={"frame": np.arange(75)}, final=head)))
    [said] = [w for w in stream.warnings if "too close to the stream's end" in w]
    assert said.startswith("on-line rig estimator: cam1: ") and f"frame {entry['frame']} " in said
    final = states[-1].extrinsics[1]  # held where the window had it: the mounting before the knock
    assert float(rotation_angle_deg(final[:3, :3].T @ truth[1, :3, :3])) < 0.5


def test_a_textureless_stretch_is_counted_not_fatal(knocked_rig):
    blank = np.full((128, 416), 128, np.uint8)
    cams = knocked_rig.cameras
    estimator = OnlineRigEstimator(np.stack([c.K for c in cams]), [tuple(c.size) for c in cams],
                                   np.stack([np.eye(4), cams[1].T_cam0_cam]))  # fmt: skip
    poses = np.linalg.inv(cams[0].poses[:1]) @ cams[0].poses
    for t in range(0, 20):
        keyframe = estimator.keyframe_next  # the images are read only for a keyframe
        state = estimator.update(t, [blank, blank] if keyframe else None, poses[t])
        assert (state is not None) == keyframe
        assert state is None or (not state.registered and np.isnan(state.std[1]).all())
    assert estimator.keyframes_unregistered == 9


def test_keypoints_of_a_distorted_camera_are_moved_to_the_pinhole_pixels_of_their_rays():
    rng = np.random.default_rng(3)
    image = cv2.GaussianBlur(rng.integers(0, 256, (128, 416)).astype(np.uint8), (0, 0), 1.5)
    lens = Distortion("fisheye", (0.05, -0.01, 0.002, 0.0))
    estimator = OnlineRigEstimator(np.stack([K, K]), [(128, 416)] * 2, np.tile(np.eye(4), (2, 1, 1)),
                                   distortions=[None, lens])  # fmt: skip
    raw, moved = estimator.map.features(image, 0), estimator.map.features(image, 1)
    assert len(moved.keypoints) == len(raw.keypoints) > 100
    reference = cv2.fisheye.undistortPoints(raw.keypoints[:, None].astype(np.float64), K, np.array(lens.coeffs), P=K)
    np.testing.assert_allclose(moved.keypoints, reference[:, 0], atol=1e-6)


def test_a_step_reaches_the_least_change_by_its_rotation_or_its_translation():
    """The least step a change must make (0.25 deg, 0.1 m), on steps built by :func:`perturbed` from a rotation about
    one axis and a translation: either part alone suffices, neither short of it does, and an unmeasured step never."""
    E = np.eye(4)
    step = lambda deg, m: innovation(E, perturbed(E, np.r_[np.radians(deg), 0, 0, 0, m, 0]))  # noqa: E731
    least = (0.25, 0.1)
    assert reaches(step(0.3, 0.0), least) and reaches(step(0.0, 0.12), least)
    assert not reaches(step(0.2, 0.08), least)
    assert not reaches(np.full(6, np.nan), least)


@pytest.mark.parametrize("persistent", [0.0, 0.5, 1.0])
def test_the_fused_covariance_covers_window_errors_that_persist(persistent):
    """40 windows a track, 300 tracks: each window's error is a share ``persistent`` of an error common to the track
    (points and keyframes the windows share) plus its own, both drawn by the window's covariance. The fused estimate's
    NEES (against the truth) stays at or under the chi-square's 95 % band whatever the share (the bound holds for any
    correlation), and within the band where the windows' errors are all common."""
    rng = np.random.default_rng(1)
    covariance = np.diag([1e-6, 4e-6, 1e-6, 1e-4, 4e-4, 1e-4])
    truth = _mounting([0, 90, 0], [0.9, 0, 0])
    statistics = []
    for _ in range(300):
        track, common = ExtrinsicTrack(), rng.multivariate_normal(np.zeros(6), covariance)
        for _ in range(40):
            own = rng.multivariate_normal(np.zeros(6), covariance)
            track.fuse(perturbed(truth, np.sqrt(persistent) * common + np.sqrt(1 - persistent) * own), covariance)
        e = innovation(track.extrinsic, truth)
        statistics.append(e @ np.linalg.solve(track.covariance, e))
    low, high = chi2.ppf([0.025, 0.975], 6 * 300) / 300
    assert np.mean(statistics) <= high
    assert (np.mean(statistics) >= low) == (persistent == 1.0)


def test_a_fused_covariance_stays_positive_and_claims_no_direction_exact():
    """A window covariance broken by rounding (a negative variance) informs nothing along that direction, and a
    direction no window informs keeps an uninformed variance: the fused covariance stays positive definite."""
    rng = np.random.default_rng(0)
    V = np.linalg.qr(rng.normal(size=(6, 6)))[0]
    good = (V * np.array([1e-6, 2e-6, 3e-6, 1e-4, 2e-4, 3e-4])) @ V.T
    broken = (V * np.array([1e-6, 2e-6, 3e-6, 1e-4, 2e-4, -5e-5])) @ V.T
    track = ExtrinsicTrack()
    track.fuse(np.eye(4), broken)
    assert np.linalg.eigvalsh(track.covariance).min() > 0
    track.fuse(np.eye(4), good)
    lam = np.linalg.eigvalsh(track.covariance)
    assert lam.min() > 0
    # the direction the broken window left out is informed by the good one alone, at its weight of one half
    np.testing.assert_allclose(V[:, 5] @ track.covariance @ V[:, 5], 2 * 3e-4, rtol=1e-6)
    # both windows inform it equally: the fused variance no smaller than either's
    np.testing.assert_allclose(V[:, 0] @ track.covariance @ V[:, 0], 1e-6, rtol=1e-6)
    lone = ExtrinsicTrack()
    lone.fuse(np.eye(4), np.eye(6) * 1e-4)
    lone.fuse(np.eye(4), broken)
    assert np.linalg.eigvalsh(lone.covariance).min() > 0


def test_a_short_stream_is_released_when_the_window_determines_it_and_states_its_error(knocked_rig):
    """50 frames of the hand-held walk, the estimator started at frame 0 with the rotation 1 deg off (as the head's
    early estimate is, and following it while the camera waits) and a zero lever arm: the camera is released once
    the window determines it, not after a fixed span; the window then turns it towards the truth, and the 1-sigma it
    states at the end covers its error (3-sigma on every axis)."""
    cams = knocked_rig.cameras
    truth = np.stack([np.linalg.inv(cams[0].T_cam0_cam) @ c.T_cam0_cam for c in cams])
    start = truth.copy()
    start[1, :3, :3] = Rotation.from_rotvec(np.radians([0.6, -0.6, 0.5])).as_matrix() @ truth[1, :3, :3]
    estimator = OnlineRigEstimator(np.stack([c.K for c in cams]), [tuple(c.size) for c in cams], start)
    poses = np.linalg.inv(cams[0].poses[:1]) @ cams[0].poses
    state = None
    for t in range(50):
        images = [cv2.imread(str(c.images[t]), cv2.IMREAD_GRAYSCALE) for c in cams]
        state = estimator.update(t, images, poses[t], start[1:, :3, :3]) or state
    assert not estimator.cameras[1].waiting and estimator.cameras[1].released_at < 40, estimator.cameras[1]
    E = state.extrinsics[1]
    error = innovation(truth[1], E)
    assert np.degrees(np.linalg.norm(error[:3])) < 0.8  # from 0.98 at the start
    assert np.all(np.abs(error) < 3 * state.std[1]), (error, state.std[1])


def test_a_track_restarted_by_a_change_fuses_afresh():
    """After a change is accepted the windows before it weigh nothing: the first window after it gives the estimate
    and the covariance (were the old windows' information kept, 50 windows at the old mounting would hold it there)."""
    covariance = np.diag([1e-6] * 3 + [1e-4] * 3)
    before, candidate, window = (_mounting([0, 90 + a, 0], [0.9, 0, 0]) for a in (0.0, 2.0, 2.5))
    track = ExtrinsicTrack()
    for _ in range(50):
        track.fuse(before, covariance)
    track.candidate = candidate
    track.accept(Change(100, 102, 2.0, 0.0))
    track.fuse(window, covariance)
    assert rotation_angle_deg(track.extrinsic[:3, :3].T @ window[:3, :3]) < 1e-3
    np.testing.assert_allclose(track.covariance, covariance, rtol=1e-3)
