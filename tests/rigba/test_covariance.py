"""The extrinsics' uncertainty: analytic Jacobians and Schur complements against a dense finite-difference solve."""

import warnings

import cv2
import numpy as np
import pytest

from ocalib.rigba.covariance import (
    ExtrinsicUncertainty,
    Observations,
    _gauge_columns,
    _jacobians,
    observations_uncertainty,
)

K = (300.0, 300.0, 208.0, 64.0)


def _pose(rvec, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64))[0]
    T[:3, 3] = t
    return T


def _problem(planar: bool, frames: int = 6, points: int = 30, noise: float = 0.3, seed: int = 0) -> Observations:
    """Two cameras, camera 1 looking left of camera 0, each seeing its own points in every frame; the rig turning about
    y only (planar) or about all axes; pixel noise ``noise``."""
    rng = np.random.default_rng(seed)
    extrinsic = _pose([0.0, -1.4, 0.05], [-0.9, 0.3, -1.0])  # T_cam0_cam1
    sensor = np.stack([np.eye(4), np.linalg.inv(extrinsic)])
    rig_from_world = []
    for f in range(frames):
        axis = [0.0, 0.15 * f, 0.0] if planar else [0.04 * np.sin(f), 0.15 * f, 0.03 * np.cos(2 * f)]
        world_from_rig = _pose(axis, [0.5 * f, 0.0 if planar else 0.1 * np.sin(f), 1.0 * f])
        rig_from_world.append(np.linalg.inv(world_from_rig))
    rig_from_world = np.stack(rig_from_world)
    camera, frame, point, xyz = [], [], [], []
    for c in range(2):
        cam_from_world0 = sensor[c] @ rig_from_world[0]
        for _ in range(points):  # points 6-15 m in front of camera c at frame 0
            p_cam = np.array([rng.uniform(-4, 4), rng.uniform(-1.5, 1.5), rng.uniform(6, 15)])
            xyz.append(np.linalg.inv(cam_from_world0)[:3] @ np.append(p_cam, 1))
            for f in range(frames):
                camera.append(c), frame.append(f), point.append(len(xyz) - 1)
    obs = Observations(
        camera=np.array(camera),
        frame=np.array(frame),
        point=np.array(point),
        xy=np.zeros((len(camera), 2)),
        rig_from_world=rig_from_world,
        xyz=np.array(xyz),
        sensor_from_rig=sensor,
        pinhole=np.tile(K, (2, 1)),
    )
    r = _jacobians(obs)[3].reshape(-1, 2)
    obs.xy = r + rng.normal(scale=noise, size=r.shape)  # residual = projection - xy = -noise
    return obs


def _exp(xi: np.ndarray) -> np.ndarray:
    return _pose(xi[:3], xi[3:])


def _residuals(obs: Observations, x: np.ndarray) -> np.ndarray:
    """Residuals with left perturbations x = [camera 1 (6), frames (6F), points (3P)] applied."""
    F, P = len(obs.rig_from_world), len(obs.xyz)
    sensor = obs.sensor_from_rig.copy()
    sensor[1] = _exp(x[:6]) @ sensor[1]
    frames = np.stack([_exp(x[6 + 6 * f : 12 + 6 * f]) @ obs.rig_from_world[f] for f in range(F)])
    xyz = obs.xyz + x[6 + 6 * F :].reshape(P, 3)
    moved = Observations(obs.camera, obs.frame, obs.point, obs.xy, frames, xyz, sensor, obs.pinhole)
    return _jacobians(moved)[3]


def _numeric_jacobian(obs: Observations) -> np.ndarray:
    """(2N, n) central differences of the residuals over every parameter, in :func:`_residuals`' order."""
    n = 6 + 6 * len(obs.rig_from_world) + 3 * len(obs.xyz)
    J = np.zeros((2 * len(obs.camera), n))
    for i in range(n):
        e = np.zeros(n)
        e[i] = 1e-6
        J[:, i] = (_residuals(obs, e) - _residuals(obs, -e)) / 2e-6
    return J


def _dense_covariance(obs: Observations, poses_held: bool = False) -> np.ndarray:
    """Camera 1's 6x6 covariance (sensor_from_rig's left perturbation) from a central-difference Jacobian of every
    parameter, the same gauge columns removed (or, with ``poses_held``, every frame's), inverted densely."""
    J = _numeric_jacobian(obs)
    n = J.shape[1]
    frames = 6 + np.arange(6 * len(obs.rig_from_world))
    keep = np.setdiff1d(np.arange(n), frames if poses_held else _gauge_columns(obs, 2))
    J = J[:, keep]
    r = _residuals(obs, np.zeros(n))
    sigma2 = r @ r / (len(r) - J.shape[1])
    return sigma2 * np.linalg.inv(J.T @ J)[:6, :6]


def _dense_covariance_with_priors(obs: Observations, noise: float) -> np.ndarray:
    """As :func:`_dense_covariance`, every parameter free and each frame's camera-0 position ``-R^T t`` a prior of
    ``noise`` per axis, its Jacobian by central differences too."""
    J = _numeric_jacobian(obs)
    n, F = J.shape[1], len(obs.rig_from_world)
    r = _residuals(obs, np.zeros(n))
    sigma2 = r @ r / (len(r) - J.shape[1] + 7)  # the images fix all but the gauge's 7

    def centres(x):
        frames = [_exp(x[6 + 6 * f : 12 + 6 * f]) @ obs.rig_from_world[f] for f in range(F)]
        return np.concatenate([-T[:3, :3].T @ T[:3, 3] for T in frames])

    P = np.zeros((3 * F, n))
    for i in range(6, 6 + 6 * F):
        e = np.zeros(n)
        e[i] = 1e-6
        P[:, i] = (centres(e) - centres(-e)) / 2e-6
    return np.linalg.inv(J.T @ J / sigma2 + P.T @ P / noise**2)[:6, :6]


def _in_camera0(obs: Observations, cov: np.ndarray) -> np.ndarray:
    """Camera 1's covariance of sensor_from_rig's left perturbation as reported, for ``E = inverse`` in camera 0's
    axes: rotation -R w, translation -R v (first order)."""
    R = np.linalg.inv(obs.sensor_from_rig[1])[:3, :3]
    A = np.zeros((6, 6))
    A[:3, :3] = A[3:, 3:] = -R
    return A @ cov @ A.T


def _assert_covariances_equal(actual: np.ndarray, expected: np.ndarray) -> None:
    """In units of the standard deviations (a correlation scale): a small off-diagonal entry's relative error is set
    by the finite differences' rounding, not by the Schur complement."""
    std = np.sqrt(np.diag(expected))
    np.testing.assert_allclose((actual - expected) / np.outer(std, std), 0, atol=1e-3)


def test_jacobians_match_central_differences():
    obs = _problem(planar=False, frames=3, points=4)
    Je, Jf, Jp, _ = _jacobians(obs)
    F = len(obs.rig_from_world)
    numeric = _numeric_jacobian(obs).reshape(len(obs.camera), 2, -1)
    for o in range(len(obs.camera)):
        if obs.camera[o] == 1:
            np.testing.assert_allclose(Je[o], numeric[o, :, :6], rtol=1e-5, atol=1e-6)
        f, p = obs.frame[o], obs.point[o]
        np.testing.assert_allclose(Jf[o], numeric[o, :, 6 + 6 * f : 12 + 6 * f], rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(Jp[o], numeric[o, :, 6 + 6 * F + 3 * p : 9 + 6 * F + 3 * p], rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("poses_held", [False, True])
def test_covariance_equals_dense_inverse(poses_held):
    obs = _problem(planar=False)
    [u] = observations_uncertainty(obs, poses_held=poses_held)
    assert len(u.unobservable) == 0
    _assert_covariances_equal(u.covariance, _in_camera0(obs, _dense_covariance(obs, poses_held)))
    assert np.all(np.isfinite(u.translation_std)) and np.all(u.translation_std > 0)


@pytest.mark.parametrize("noise", [0.01, 0.3])
def test_covariance_with_position_priors_equals_dense_inverse(noise):
    """Poses solved with camera 0's positions as priors (no gauge fixed): as a dense inverse of every parameter's
    information, the priors' rows included."""
    obs = _problem(planar=False)
    [u] = observations_uncertainty(obs, weak_share=0.0, position_noise=noise)
    _assert_covariances_equal(u.covariance, _in_camera0(obs, _dense_covariance_with_priors(obs, noise)))


def test_tighter_position_priors_know_the_extrinsic_better():
    """Each variance falls as the priors tighten, and stays above the held poses' (which also give the rotations);
    on a planar drive, whose collinear positions leave a rotation of the whole free, the height stays unobservable."""
    obs = _problem(planar=False)
    [held] = observations_uncertainty(obs, weak_share=0.0, poses_held=True)
    variances = [
        np.diag(observations_uncertainty(obs, weak_share=0.0, position_noise=n)[0].covariance) for n in (1.0, 0.1, 0.01)
    ]
    assert np.all(np.diff(variances, axis=0) < 0) and np.all(variances[-1] > np.diag(held.covariance))
    [planar] = observations_uncertainty(_problem(planar=True), position_noise=0.05)
    assert planar.unobservable.shape == (1, 3) and np.isinf(planar.translation_std[1])
    assert np.all(np.isfinite(planar.translation_std[[0, 2]])) and np.all(np.isfinite(planar.rotation_std))


def test_planar_motion_leaves_the_height_unobservable():
    """The rig turning about y only: camera 1's translation along y (camera 0's axes) is reported unobservable and
    its standard deviation is not a number; the two in-plane directions keep finite ones."""
    [u] = observations_uncertainty(_problem(planar=True))
    assert u.unobservable.shape == (1, 3)
    assert abs(u.unobservable[0, 1]) == pytest.approx(1.0, abs=1e-3)
    std = u.translation_std
    assert np.isinf(std[1]) and np.all(np.isfinite(std[[0, 2]]))
    assert np.all(np.isfinite(u.rotation_std))


def test_a_translation_variance_rounded_below_zero_gives_no_warning():
    """Along an unobservable direction the covariance's variance is 0 up to rounding, which may fall below 0: the
    axis it touches reports inf and the others their standard deviation, without a warning of a square root."""
    cov = np.diag([1e-6, 1e-6, 1e-6, 4e-4, -2e-16, 9e-4])
    u = ExtrinsicUncertainty(cov, np.array([[0.0, 1.0, 0.0]]))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.testing.assert_allclose(u.translation_std, [0.02, np.inf, 0.03])
        assert ExtrinsicUncertainty(cov, np.zeros((0, 3))).translation_std[1] == 0


def test_held_poses_know_the_extrinsic_better():
    """Poses given, not estimated: every variance of the extrinsic is smaller than with the poses free."""
    obs = _problem(planar=False)
    [free], [held] = observations_uncertainty(obs), observations_uncertainty(obs, poses_held=True)
    assert np.all(np.diag(held.covariance) < np.diag(free.covariance))
