"""Depth and pose metrics against hand-computed cases, known similarity transforms, OpenCV's Umeyama and
synthetic noise of known size."""

import cv2
import numpy as np
import pytest

from ocalib.errors import InputError
from ocalib.eval.depth_metrics import depth_errors, mean_depth_errors
from ocalib.eval.pose_metrics import (
    congruence_residual,
    frame_errors,
    frame_motions,
    pose_metrics,
    rotation_gain,
    rpe,
    snippet_ate,
)
from ocalib.geometry.alignment import align_poses, align_trajectory, umeyama
from ocalib.geometry.se3 import chain_motions, rotation_angle_deg, so3_log


def rot(axis, angle):
    """Rodrigues rotation (3, 3) about ``axis`` by ``angle`` radians."""
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * Kx + (1 - np.cos(angle)) * Kx @ Kx


def pose(R, t):
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def trajectory(n=40, seed=0):
    """A curving, pitching camera-to-world trajectory (n, 4, 4), ~1 unit a frame forward."""
    rng = np.random.default_rng(seed)
    P = [np.eye(4)]
    for _ in range(n - 1):
        step = pose(rot(rng.normal(size=3) + [0, 3, 0], rng.uniform(0.01, 0.08)), [0.1 * rng.normal(), 0.05, 1.0])
        P.append(P[-1] @ step)
    return np.stack(P)


def similarity(P, s, R, t):
    """A trajectory expressed in another world frame and unit: the transform (s, R, t) applied to it."""
    return align_poses(P, s, R, t)


# --- Umeyama -------------------------------------------------------------------------------------------


def test_umeyama_recovers_known_similarity():
    rng = np.random.default_rng(1)
    src = rng.normal(size=(30, 3)) * [3, 1, 0.5]
    R = rot([0.3, -1, 0.4], 2.5)
    dst = 0.37 * src @ R.T + [4.0, -2.0, 9.0]
    s, R_est, t = umeyama(src, dst)
    assert s == pytest.approx(0.37, rel=1e-12)
    np.testing.assert_allclose(R_est, R, atol=1e-12)
    np.testing.assert_allclose(t, [4.0, -2.0, 9.0], atol=1e-12)
    assert umeyama(src, dst, with_scale=False)[0] == 1.0


def test_umeyama_matches_opencv_on_noisy_points():
    rng = np.random.default_rng(2)
    src = rng.normal(size=(50, 3))
    dst = 2.3 * src @ rot([1, 2, 3], 0.7).T + [1, 2, 3] + 0.2 * rng.normal(size=(50, 3))
    s, R, t = umeyama(src, dst)
    M, s_cv = cv2.estimateAffine3D(src, dst, force_rotation=True)
    assert s == pytest.approx(s_cv, rel=1e-9)
    np.testing.assert_allclose(R, M[:, :3], atol=1e-9)
    np.testing.assert_allclose(t, M[:, 3], atol=1e-9)


def test_umeyama_is_a_least_squares_minimum_and_never_a_reflection():
    rng = np.random.default_rng(3)
    src = rng.normal(size=(20, 3))
    dst = src * [1, 1, -1] + 0.05 * rng.normal(size=(20, 3))  # a mirror image: best proper rotation wanted
    s, R, t = umeyama(src, dst)
    assert np.linalg.det(R) == pytest.approx(1.0)
    cost = lambda s, R, t: ((dst - s * src @ R.T - t) ** 2).sum()  # noqa: E731
    best = cost(s, R, t)
    for k in range(50):
        dR = rot(rng.normal(size=3), 1e-3)
        assert cost(s * (1 + 1e-3 * rng.normal()), dR @ R, t + 1e-3 * rng.normal(size=3)) > best


def test_umeyama_rejects_points_without_spread():
    with pytest.raises(InputError, match="same place"):
        umeyama(np.ones((5, 3)), np.random.default_rng(0).normal(size=(5, 3)))


def test_align_trajectory_undoes_a_similarity():
    gt = trajectory()
    pred = similarity(gt, 0.2, rot([0, 0, 1], 1.0), np.array([5.0, 0, -1]))
    aligned, sim3 = align_trajectory(pred, gt)
    np.testing.assert_allclose(aligned, gt, atol=1e-9)
    assert sim3["scale"] == pytest.approx(5.0)


# --- depth ---------------------------------------------------------------------------------------------


def test_depth_errors_hand_computed():
    gt = np.array([[1.0, 2.0], [4.0, 0.0]])  # 0: no ground truth
    pred = np.array([[1.0, 2.0], [2.0, 7.0]])
    m = depth_errors(pred, gt, median_scaling=False)
    assert m["valid"] == 3 and m["scale"] == 1.0
    assert m["abs_rel"] == pytest.approx(0.5 / 3)
    assert m["sq_rel"] == pytest.approx(1.0 / 3)
    assert m["rmse"] == pytest.approx(np.sqrt(4 / 3))
    assert m["rmse_log"] == pytest.approx(np.log(2) / np.sqrt(3))
    assert m["a1"] == m["a2"] == m["a3"] == pytest.approx(2 / 3)  # ratio 2 > 1.25^3 = 1.95
    # median scaling removes any global factor of the prediction
    scaled = depth_errors(5 * pred, gt)
    assert scaled["scale"] == pytest.approx(0.2)
    for key in ("abs_rel", "sq_rel", "rmse", "rmse_log", "a1"):
        assert scaled[key] == pytest.approx(m[key])


def test_depth_caps_and_mean():
    gt = np.array([[1.0, 100.0, 5e-4, 2.0]])
    pred = np.array([[1.0, 1.0, 1.0, 3.0]])
    m = depth_errors(pred, gt, min_depth=1e-3, max_depth=80, median_scaling=False)
    assert m["valid"] == 2 and m["abs_rel"] == pytest.approx(0.25)
    assert depth_errors(pred, gt, max_depth=150, median_scaling=False)["valid"] == 3
    assert depth_errors(pred, np.zeros_like(gt)) is None
    mean = mean_depth_errors([m, None, depth_errors(gt, gt, median_scaling=False)])
    assert mean["images"] == 2 and mean["skipped"] == 1
    assert mean["abs_rel"] == pytest.approx(0.125) and mean["a1"] == pytest.approx(0.75)


def test_errors_by_true_depth_range_hand_computed():
    """Pooled over the pixels of all images, per ground-truth range; a compressed depth range (pred ~ gt^0.7) is
    too far near the camera and too near far from it."""
    gt = np.array([[2.0, 8.0, 30.0, 60.0]])
    pred = np.array([[3.0, 8.0, 24.0, 30.0]])
    m = depth_errors(pred, gt, median_scaling=False)
    assert m["range_pixels"] == [1, 1, 0, 1, 1]
    np.testing.assert_allclose(m["range_signed_rel_sum"], [0.5, 0.0, 0.0, -0.2, -0.5])
    np.testing.assert_allclose(m["range_abs_rel_sum"], [0.5, 0.0, 0.0, 0.2, 0.5])
    other = depth_errors(np.array([[1.0, 4.0]]), np.array([[2.0, 4.0]]), median_scaling=False)  # 2 pixels, 0-5 m
    by_range = mean_depth_errors([m, other])["by_range"]
    assert [r["range_m"] for r in by_range] == [[0.0, 5.0], [5.0, 10.0], [20.0, 40.0], [40.0, None]]
    assert by_range[0]["share"] == pytest.approx(3 / 6) and by_range[0]["signed_rel"] == pytest.approx((0.5 - 0.5) / 3)
    assert by_range[0]["abs_rel"] == pytest.approx((0.5 + 0.5) / 3)
    assert by_range[3]["signed_rel"] == pytest.approx(-0.5) and sum(r["share"] for r in by_range) == pytest.approx(1)
    gt = np.random.default_rng(0).uniform(1, 79, size=(40, 50))
    signed = [r["signed_rel"] for r in mean_depth_errors([depth_errors(gt**0.7, gt)])["by_range"]]
    assert signed[0] > 0 > signed[-1] and np.all(np.diff(signed) < 0)


def test_perfect_depth_gives_zero_error():
    gt = np.random.default_rng(0).uniform(1, 60, size=(8, 10))
    m = depth_errors(gt * 0.01, gt)
    assert m["abs_rel"] < 1e-12 and m["rmse"] < 1e-10 and m["a1"] == 1.0


# --- pose ----------------------------------------------------------------------------------------------


def test_snippet_ate_hand_computed_and_invariant():
    gt = np.stack([pose(np.eye(3), [0, 0, z]) for z in range(5)])
    pred = np.stack([pose(np.eye(3), [0, 0, z]) for z in (0, 1, 2, 3, 5)])
    # s = 34/39; errors 0, -5/39, -10/39, -15/39, 14/39; ||.|| / 5
    assert snippet_ate(pred, gt)[0] == pytest.approx(np.sqrt(546) / 39 / 5)
    moved = similarity(pred, 7.0, rot([1, 1, 0], 0.5), np.array([3.0, 2, 1]))  # any world frame and unit
    assert snippet_ate(moved, gt)[0] == pytest.approx(np.sqrt(546) / 39 / 5)
    P = trajectory(12)
    assert snippet_ate(similarity(P, 0.1, rot([0, 1, 0], 2.0), np.zeros(3)), P) == pytest.approx(np.zeros(8), abs=1e-12)


def test_rpe_of_a_constant_motion_error():
    gt = trajectory(30)
    E = pose(rot([1, 0, 0], np.radians(2.0)), [0.1, 0.0, 0.2])
    motions = np.linalg.inv(gt[:-1]) @ gt[1:]
    pred = [np.eye(4)]
    for M in motions:
        pred.append(pred[-1] @ M @ E)
    trans, rot_deg = rpe(np.stack(pred), gt, delta=1)
    np.testing.assert_allclose(trans, np.hypot(0.1, 0.2), rtol=1e-9)
    np.testing.assert_allclose(rot_deg, 2.0, rtol=1e-9)


def test_frame_errors_known_rotation_direction_and_scale():
    gt = trajectory(21)
    motions = np.linalg.inv(gt[:-1]) @ gt[1:]
    motions[5, :3, 3] = 0  # a stand-still frame: no direction, no ratio
    gt = chain_motions(motions)
    ratios = np.array([1.0, 3.0] * 10)
    pred = []
    for k, M in enumerate(motions):
        axis = np.cross(M[:3, 3], [0, 1, 0]) if np.linalg.norm(M[:3, 3]) else np.array([0, 1.0, 0])
        pred.append(
            pose(M[:3, :3] @ rot([0, 0, 1], np.radians(0.5)), ratios[k] * rot(axis, np.radians(4.0)) @ M[:3, 3])
        )
    e = frame_errors(chain_motions(np.stack(pred)), gt)
    np.testing.assert_allclose(e["rotation_deg"], 0.5, rtol=1e-9)
    assert not e["moving"][5] and e["moving"].sum() == 19
    np.testing.assert_allclose(e["direction_deg"][e["moving"]], 4.0, rtol=1e-9)
    np.testing.assert_allclose(e["scale_ratio"][e["moving"]], ratios[e["moving"]], rtol=1e-9)
    assert np.isnan(e["direction_deg"][5]) and np.isnan(e["scale_ratio"][5])


def test_pose_metrics_perfect_predictor_is_zero():
    gt = trajectory(30)
    pred = similarity(gt, 0.05, rot([1, 2, 3], 1.0), np.array([1.0, 2, 3]))
    summary, details = pose_metrics(pred, gt)
    for key in (
        "sfmlearner_5frame_snippet_ate",
        "ate_rmse",
        "rpe_trans_rmse",
        "rpe_rot_rmse_deg",
        "rotation_error_deg_median",
        "direction_error_deg_median",
        "scale_ratio_cv",
    ):
        assert summary[key] == pytest.approx(0, abs=1e-6), key
    assert summary["scale_ratio_median"] == pytest.approx(0.05) and summary["ate_sim3_scale"] == pytest.approx(20)
    np.testing.assert_allclose(details["aligned"], gt, atol=1e-9)


def test_ate_of_isotropic_position_noise():
    """Positions with N(0, sigma^2) noise per axis: after alignment (7 of 3N dof absorbed), ATE ~ sigma sqrt(3)."""
    rng = np.random.default_rng(4)
    gt = trajectory(3000, seed=5)
    pred = gt.copy()
    pred[:, :3, 3] += 0.05 * rng.normal(size=(3000, 3))
    summary, _ = pose_metrics(similarity(pred, 3.0, rot([0, 1, 0], 0.3), np.zeros(3)), gt)
    assert summary["ate_rmse"] == pytest.approx(0.05 * np.sqrt(3 * (1 - 7 / 9000)), rel=0.03)


def test_pose_metrics_rejects_static_ground_truth():
    gt = np.tile(np.eye(4), (10, 1, 1))
    with pytest.raises(InputError, match="does not move"):
        pose_metrics(trajectory(10), gt)


def test_rotation_angle_small_and_large():
    assert rotation_angle_deg(rot([1, 1, 1], 1e-7))[()] == pytest.approx(np.degrees(1e-7), rel=1e-6)
    assert rotation_angle_deg(rot([0, 1, 0], np.radians(179.0)))[()] == pytest.approx(179.0)


def test_baselines_are_the_metrics_of_image_blind_predictors():
    gt = trajectory(40, seed=7)
    summary, _ = pose_metrics(gt, gt)
    truth = frame_motions(gt)
    units = truth[:, :3, 3] / np.linalg.norm(truth[:, :3, 3], axis=1, keepdims=True)
    direction = units.mean(0) / np.linalg.norm(units.mean(0))
    blind = chain_motions(np.stack([pose(np.eye(3), 0.5 * direction) for _ in truth]))  # no rotation, fixed step
    e = frame_errors(blind, gt)
    assert summary["baseline_zero_rotation_deg_median"] == pytest.approx(np.median(e["rotation_deg"]))
    assert summary["baseline_zero_rotation_deg_mean"] == pytest.approx(np.mean(e["rotation_deg"]))
    assert summary["baseline_constant_direction_deg_median"] == pytest.approx(np.median(e["direction_deg"]))
    blind_summary, _ = pose_metrics(blind, gt)
    assert summary["baseline_constant_step_scale_cv"] == pytest.approx(blind_summary["scale_ratio_cv"])
    assert summary["baseline_zero_rotation_deg_median"] > 1  # the test trajectory turns 0.6-4.6 deg a frame


def test_axis_angle_matches_opencv_rodrigues():
    rng = np.random.default_rng(3)
    R = np.stack([rot(rng.normal(size=3), a) for a in (1e-9, 1e-4, 0.3, 2.0, 3.0)])
    expected = np.stack([cv2.Rodrigues(r)[0].ravel() for r in R])
    np.testing.assert_allclose(so3_log(R), expected, atol=1e-9)


def test_rotation_gain_recovers_per_axis_scaling():
    """A predictor that reports 0.5x the rotation about x, 1x about y and 0.25x about z (its translation
    exact), and one that never rotates about z: their gains, and NaN about an axis the truth never turns."""
    gt = trajectory(60, seed=5)
    truth = frame_motions(gt)
    rv = so3_log(truth[:, :3, :3])
    gains = np.array([0.5, 1.0, 0.25])
    pred = np.stack([pose(cv2.Rodrigues(gains * r)[0], m[:3, 3]) for r, m in zip(rv, truth)])
    summary, _ = pose_metrics(chain_motions(pred), gt)
    np.testing.assert_allclose(summary["rotation_gain_xyz"], gains, atol=1e-9)
    flat = np.stack([pose(rot([0, 1, 0], 0.02 * (i % 3)), [0, 0, 1]) for i in range(30)])  # turns about y only
    g = rotation_gain(flat, flat)
    assert np.isnan(g[[0, 2]]).all() and g[1] == pytest.approx(1.0)


def _rig(gain: float = 1.0, noise_deg: float = 0.0, frames: int = 60, seed: int = 0) -> np.ndarray:
    """Trajectories (T, 2, 4, 4) of a rigid two-camera rig turning about random axes, every rotation angle scaled
    by ``gain``, camera 1's motions turned further by ``noise_deg`` about random axes."""
    rng = np.random.default_rng(seed)
    X = np.eye(4)
    X[:3, :3], X[:3, 3] = rot([0.2, 1.0, 0.1], 2.0), [0.5, 0.0, -0.3]  # T_cam0_cam1
    poses = [np.tile(np.eye(4), (2, 1, 1))]
    for _ in range(frames - 1):
        A = np.eye(4)
        A[:3, :3], A[:3, 3] = rot(rng.normal(size=3), gain * np.radians(rng.uniform(0.5, 3.0))), rng.normal(size=3)
        B = np.linalg.inv(X) @ A @ X  # the rigid rig's motion of camera 1: A X = X B
        B[:3, :3] = rot(rng.normal(size=3), np.radians(noise_deg)) @ B[:3, :3]
        poses.append(np.stack([poses[-1][0] @ A, poses[-1][1] @ B]))
    return np.stack(poses)


def test_congruence_residual_is_zero_on_a_rigid_rig_whatever_the_gain_and_grows_with_noise():
    assert congruence_residual(_rig()) < 1e-9
    assert congruence_residual(_rig(gain=0.5)) < 1e-9  # both cameras under-reporting alike: still congruent
    noisy = [congruence_residual(_rig(noise_deg=n)) for n in (0.05, 0.2, 0.8)]
    assert 0 < noisy[0] < noisy[1] < noisy[2]
    still = np.tile(np.eye(4), (10, 2, 1, 1))
    assert np.isnan(congruence_residual(still))  # nothing turns: nothing to rank by
