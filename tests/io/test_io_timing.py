"""Timestamp association between the cameras of a rig: nearest stamp and interpolation."""

import cv2
import numpy as np
import pytest

from ocalib.errors import InputError
from ocalib.io.timing import associate, interpolate


def brute_force_associate(t0, t1, max_dt):
    """Nearest neighbour by an O(N^2) search, then the closest camera-0 stamp per camera-1 stamp."""
    d = np.abs(t0[:, None] - t1[None])
    j = d.argmin(1)
    best = {}
    for i, (jj, dt) in enumerate(zip(j, d[np.arange(len(t0)), j])):
        if dt <= max_dt and (jj not in best or dt < best[jj][1]):
            best[jj] = (i, dt)
    pairs = sorted((i, jj) for jj, (i, _) in best.items())
    return np.array([p[0] for p in pairs], int), np.array([p[1] for p in pairs], int)


def test_associate_matches_brute_force():
    rng = np.random.default_rng(0)
    t0 = np.cumsum(rng.uniform(0.02, 0.05, 400))
    t1 = np.cumsum(rng.uniform(0.01, 0.12, 200)) + 0.3
    for max_dt in (0.005, 0.02, 1.0):
        i0, i1 = associate(t0, t1, max_dt)
        e0, e1 = brute_force_associate(t0, t1, max_dt)
        np.testing.assert_array_equal(i0, e0)
        np.testing.assert_array_equal(i1, e1)
        assert (np.diff(i0) > 0).all() and (np.diff(i1) > 0).all()
        assert (np.abs(t0[i0] - t1[i1]) <= max_dt).all()
    i0, i1 = associate(t0, t0[5::7], 0.0)  # exact matches survive max_dt = 0
    np.testing.assert_array_equal(i0, np.arange(5, 400, 7))


def test_associate_one_to_one_and_offset():
    t0 = np.arange(0, 10, 0.1)  # 10 Hz
    t1 = np.arange(0, 10, 0.5) + 100.02  # 2 Hz on another clock
    i0, i1 = associate(t0, t1, 0.03, offset=-100.0)
    np.testing.assert_array_equal(i1, np.arange(20))  # each camera-1 stamp once, to its closest
    np.testing.assert_allclose(t0[i0], np.arange(0, 10, 0.5), atol=1e-9)
    with pytest.raises(InputError, match="no timestamp pair within max_dt = 0.01 s.*closest is 0.020000 s"):
        associate(t0, t1, 0.01, offset=-100.0)


def test_associate_never_overlapping_ranges():
    t0 = np.arange(0, 10, 0.1) + 1.7e9
    t1 = np.arange(0, 10, 0.1) + 12.0
    with pytest.raises(InputError) as err:
        associate(t0, t1, 0.01, names=("cam0.txt", "cam1.txt"))
    message = str(err.value)
    assert "cam0.txt spans [1700000000.000000, 1700000009.900000] s" in message
    assert "cam1.txt spans [12.000000, 21.900000] s" in message
    assert "never overlap" in message and "--time-offset auto" in message


def test_associate_rejects_unsorted_times():
    with pytest.raises(InputError, match="cam1: timestamps must be finite and strictly increasing"):
        associate([0.0, 1.0], [1.0, 0.5], 0.1, names=("cam0", "cam1"))


def screw_motion(t: float, w=(0.3, -0.5, 0.8), v=(1.0, 0.2, -0.4)) -> np.ndarray:
    """Camera-to-world pose (4, 4) at time t of a constant angular and linear velocity (the closed form SLERP and
    linear interpolation must reproduce exactly)."""
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.multiply(w, t))[0]
    T[:3, 3] = np.multiply(v, t) + 0.5
    return T


@pytest.mark.parametrize("offset", [0.0, -0.0123])
def test_interpolate_is_exact_on_constant_velocity(offset):
    t1 = np.arange(0.0, 3.0, 1 / 30)  # camera 1 at 30 Hz; camera 0 at 20 Hz, another phase
    t0 = np.arange(0.01, 3.2, 1 / 20)
    poses1 = np.stack([screw_motion(t + offset) for t in t1])  # camera 1's clock: t0 = t1 + offset
    i0, poses, _ = interpolate(t0, t1, poses1, max_dt=1 / 30, offset=offset)
    inside = (t0 >= t1[0] + offset) & (t0 <= t1[-1] + offset)
    np.testing.assert_array_equal(i0, np.flatnonzero(inside))
    np.testing.assert_allclose(poses, np.stack([screw_motion(t) for t in t0[i0]]), atol=1e-12, rtol=0)


def test_interpolate_keeps_samples_and_drops_gaps():
    t1 = np.array([0.0, 0.1, 0.2, 0.5, 0.6])  # a gap of 0.3 s between 0.2 and 0.5
    poses1 = np.stack([screw_motion(t) for t in t1])
    t0 = np.array([-0.05, 0.0, 0.05, 0.2, 0.3, 0.5, 0.55, 0.6, 0.7])
    i0, poses, i1 = interpolate(t0, t1, poses1, max_dt=0.1)
    np.testing.assert_array_equal(t0[i0], [0.0, 0.05, 0.2, 0.5, 0.55, 0.6])  # not before/after, not in the gap
    on_sample = np.isin(t0[i0], t1)
    np.testing.assert_array_equal(poses[on_sample], poses1[i1[on_sample]])  # samples as they are
    with pytest.raises(InputError, match="cam1.*spans.*never overlap"):
        interpolate(np.array([1.0, 2.0]), t1, poses1, 0.1, names=("cam0", "cam1"))
    with pytest.raises(
        InputError,
        match=r"no cam0 stamp between two cam1 samples at most 2 max_dt = 0.1 s apart.*"
        r"closest is 0.300000 s",
    ):
        interpolate(np.array([0.3, 0.4]), t1, poses1, 0.05, names=("cam0", "cam1"))


def test_interpolate_marks_poses_from_invalid_samples():
    t1 = np.array([0.0, 0.1, 0.2, 0.3, 0.4, 0.5])
    poses1 = np.stack([screw_motion(t) for t in t1])
    poses1[2, 0, 0] = np.nan  # sample 2 invalid
    t0 = np.array([0.15, 0.2, 0.25, 0.3, 0.35])
    i0, poses, i1 = interpolate(t0, t1, poses1, max_dt=0.1)
    bad = np.isnan(poses).any(axis=(1, 2))
    np.testing.assert_array_equal(bad, [True, True, True, False, False])  # every pose that leans on sample 2
    np.testing.assert_array_equal(i1[bad], [2, 2, 2])  # named by the invalid sample (its file line)
