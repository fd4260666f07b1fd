"""The front end's geometry on exact synthetic data: triangulation, scale votes, joint refinement, the window
bundle adjustment and the evaluation metrics recover the generating values."""

import cv2
import numpy as np
import pytest

from ocalib.eval.pose_metrics import step_errors
from ocalib.frontend.refine import refine_motion
from ocalib.frontend.twoview import bearings, parallax_px, rotation_from_bearings, scale_along, triangulate
from ocalib.frontend.window import bundle_adjust, window_problem

K = np.array([[208.0, 0, 207.5], [0, 204.8, 63.5], [0, 0, 1]])


def _pose(rvec, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.asarray(rvec, float))[0]
    T[:3, 3] = t
    return T


def _project(points_world, pose):
    """Pixels (N, 2) of world points in a camera-to-world pose."""
    inv = np.linalg.inv(pose)
    p = points_world @ inv[:3, :3].T + inv[:3, 3]
    return np.stack([K[0, 0] * p[:, 0] / p[:, 2] + K[0, 2], K[1, 1] * p[:, 1] / p[:, 2] + K[1, 2]], 1)


@pytest.fixture
def scene():
    rng = np.random.default_rng(0)
    points = np.stack([rng.uniform(-6, 6, 300), rng.uniform(-3, 1.5, 300), rng.uniform(4, 40, 300)], 1)
    poses = np.stack([_pose([0.01 * i, 0.02 * i, -0.005 * i], [0.05 * i, 0.01 * i, 0.3 * i]) for i in range(8)])
    return points, poses


def test_triangulation_and_scale_votes_are_exact(scene):
    points, poses = scene
    T_b_a = np.linalg.inv(poses[3]) @ poses[0]  # p_b = R p_a + t
    ba, bb = bearings(_project(points, poses[0]), K), bearings(_project(points, poses[3]), K)
    X, angle = triangulate(ba, bb, T_b_a[:3, :3], T_b_a[:3, 3])
    inv0 = np.linalg.inv(poses[0])
    conditioned = angle > np.radians(0.2)  # rays through the epipole are parallel: no depth there
    assert conditioned.mean() > 0.5
    np.testing.assert_allclose(X[conditioned], (points @ inv0[:3, :3].T + inv0[:3, 3])[conditioned], rtol=1e-8)
    assert (angle > 0).all()
    s, sin = scale_along(X, bb, T_b_a[:3, :3], T_b_a[:3, 3] / 2.0)  # half the translation: every vote says 2
    np.testing.assert_allclose(s[sin > 0.05], 2.0, rtol=1e-9)


def test_rotation_only_motion_has_no_parallax(scene):
    points, poses = scene
    rotated = poses[0] @ _pose([0.02, -0.03, 0.01], [0, 0, 0])
    ba, bb = bearings(_project(points, poses[0]), K), bearings(_project(points, rotated), K)
    R = rotation_from_bearings(ba, bb)
    np.testing.assert_allclose(R, (np.linalg.inv(rotated) @ poses[0])[:3, :3], atol=1e-12)
    assert parallax_px(ba, bb, R, K).max() < 1e-8


@pytest.mark.parametrize("landmarks", [True, False])
def test_refinement_recovers_the_motion(scene, landmarks):
    points, poses = scene
    T = np.linalg.inv(poses[1]) @ poses[0]  # p_b = R p_a + t
    ua, ub = _project(points, poses[0]), _project(points, poses[1])
    ba, bb = bearings(ua, K), bearings(ub, K)
    inv0 = np.linalg.inv(poses[0])
    X = points[:50] @ inv0[:3, :3].T + inv0[:3, 3] if landmarks else np.zeros((0, 3))
    R0 = cv2.Rodrigues(np.array([0.01, -0.01, 0.005]))[0] @ T[:3, :3]
    t0 = (T[:3, 3] + [0.02, -0.01, 0.0]) * (1.2 if landmarks else 1.0)  # landmarks fix the length
    R, t, cost, r = refine_motion(R0, t0, ba, bb, X, ub[: len(X)], K)
    np.testing.assert_allclose(R, T[:3, :3], atol=1e-7)
    if landmarks:
        np.testing.assert_allclose(t, T[:3, 3], atol=1e-7)
    else:  # direction only; the length is kept
        np.testing.assert_allclose(t / np.linalg.norm(t), T[:3, 3] / np.linalg.norm(T[:3, 3]), atol=1e-7)
        assert np.linalg.norm(t) == pytest.approx(np.linalg.norm(t0))
    assert cost < 1e-10 and np.abs(r).max() < 1e-5


def test_window_bundle_adjustment_recovers_poses_and_depths(scene):
    points, poses = scene
    rng = np.random.default_rng(1)
    history = []
    for f, pose in enumerate(poses):  # every point seen by frames 0..7, ids sorted
        seen = np.flatnonzero(rng.random(len(points)) < 0.8)
        history.append((f, seen, _project(points[seen], pose)))
    ids, frame, landmark, px, anchor, bearing, rho = window_problem(history, poses, K)
    depth = np.array([(np.linalg.inv(poses[a]) @ np.r_[points[i], 1])[2] for i, a in zip(ids, anchor)])
    np.testing.assert_allclose(rho, 1 / depth, rtol=1e-6)  # two-ray initialisation is exact on exact data
    counts = np.bincount(np.concatenate([h[1] for h in history]), minlength=len(points))
    assert set(ids) == set(np.flatnonzero(counts >= 3))
    noisy = poses.copy()
    for f in range(2, len(poses)):
        noisy[f] = noisy[f] @ _pose(rng.normal(0, 0.01, 3), rng.normal(0, 0.03, 3))
    out, rho_out, err = bundle_adjust(noisy, 2, frame, landmark, px, anchor, bearing, rho * 1.1, K, iterations=20)
    np.testing.assert_array_equal(out[:2], noisy[:2])  # held frames
    np.testing.assert_allclose(out, poses, atol=1e-6)
    np.testing.assert_allclose(rho_out, 1 / depth, rtol=1e-6)
    assert err.max() < 1e-4


def test_motion_errors_measure_known_perturbations(scene):
    _, gt = scene
    pred = gt.copy()
    pred[:, :3, 3] *= 3.0  # another unit: no error at all
    e = step_errors(pred, gt)
    assert e["rotation_deg"].max() < 1e-6 and e["direction_deg"].max() < 1e-5 and e["scale_cv"] < 1e-9
    np.testing.assert_allclose(e["scale_ratio"], 3.0)
    steps = np.linalg.inv(pred[:-1]) @ pred[1:]
    steps[3] = steps[3] @ _pose([0, np.radians(2.0), 0], [0, 0, 0])  # the motion into frame 4 turns 2 deg more
    bent = [pred[0]]
    for step in steps:
        bent.append(bent[-1] @ step)
    bent = np.stack(bent)
    e = step_errors(bent, gt, valid=np.arange(8) != 6)
    assert e["rotation_deg"][3] == pytest.approx(2.0) and np.delete(e["rotation_deg"], 3).max() < 1e-6
    assert e["valid"].tolist() == [True] * 5 + [False, True]
