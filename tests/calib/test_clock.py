"""Clock offsets from motion: the angular-speed correlation and its refinement by the rig's rotation constraint,
against rigs whose offset is known by construction."""

import re

import cv2
import numpy as np
import pytest
import torch
from timed_rigs import make_rig

from ocalib.calib.drivers.clock import (
    _runner_up,
    angular_speed,
    estimate_time_offset,
    find_time_offset,
    refine_time_offset,
)
from ocalib.errors import InputError
from ocalib.io.poses import read_poses, write_tum
from ocalib.io.timing import associate
from ocalib.sim.trajectory import add_noise, random_rig

FRAME = 1 / 30  # camera 0's frame period, seconds


@pytest.fixture
def rig():
    """The synthetic rig generator, :func:`make_rig`."""
    return make_rig


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_offset_unix_against_boot_clock(rig, seed):
    t0, p0, t1, p1 = rig(seed, jitter1=0.3)
    offset, quality = estimate_time_offset(t0 + 1_700_000_000.0, p0, t1 + 5.25, p1)
    assert abs(offset - (1_700_000_000.0 - 5.25)) < 0.2 * FRAME
    assert quality.correlation > 0.9 and quality.runner_up < quality.correlation
    assert quality.overlap > 55


def test_offset_1234_567_with_noise_through_files(tmp_path, rig):
    t0, p0, t1, p1 = rig(3, jitter1=0.3, noise=0.01)
    write_tum(tmp_path / "cam0.tum", t0, p0)
    write_tum(tmp_path / "cam1.tum", t1 + 1234.567, p1)
    cam0, cam1 = read_poses(tmp_path / "cam0.tum"), read_poses(tmp_path / "cam1.tum")
    offset, _ = estimate_time_offset(cam0.times, cam0.poses, cam1.times, cam1.poses)
    assert abs(offset + 1234.567) < 0.2 * FRAME  # t0 = t1 + offset
    # Sign convention: the offset puts camera 1 on camera 0's clock for association.
    with pytest.raises(InputError, match="--time-offset auto"):
        associate(cam0.times, cam1.times, 0.01)
    i0, i1 = associate(cam0.times, cam1.times, FRAME / 2, offset=offset)
    np.testing.assert_array_equal(i1, np.arange(len(t1)))  # every 20 Hz frame has a 30 Hz partner
    assert np.abs(t0[i0] - t1[i1]).max() < FRAME / 2 + 0.2 * FRAME


def test_offset_with_partial_overlap_and_invalid_poses(rig):
    t0, p0, t1, p1 = rig(4, start1=48.0)  # camera 1 sees only the last 12 s of camera 0's 60 s
    p0[[10, 11, 300]] = np.nan
    offset, quality = estimate_time_offset(t0, p0, t1 - 1234.567, p1)
    assert abs(offset - 1234.567) < 0.2 * FRAME
    assert 11 < quality.overlap < 12.1


def test_offset_barely_overlapping_recordings_is_an_error(rig):
    t0, p0, t1, p1 = rig(0, duration=115)
    keep0, keep1 = t0 < 60, t1 > 55  # 5 s shared of two 60 s recordings
    with pytest.raises(InputError, match="ambiguous time offset|no clear time offset"):
        estimate_time_offset(t0[keep0], p0[keep0], t1[keep1], p1[keep1])


def _repeating(t: np.ndarray) -> np.ndarray:
    """Poses (N, 4, 4) whose rotation vector repeats with a flipped sign every 10 pi s (the same angular speed)."""
    T = np.tile(np.eye(4), (len(t), 1, 1))
    for P, s in zip(T, t):
        P[:3, :3] = cv2.Rodrigues(
            np.array([0.6 * np.sin(1.1 * s), 0.5 * np.sin(0.7 * s + 1), 0.4 * np.sin(0.9 * s + 2)])
        )[0]
    return T


@pytest.mark.parametrize("noise", [0.0, 0.002])
def test_offset_of_a_repeating_motion_is_ambiguous(noise):
    """A motion whose angular speed repeats every 10 pi s: two lags correlate alike (to within 1e-5 of perfect
    without noise), and the answer is an error, not the better of the two by a hair; pose noise, which broadens
    each peak, does not hide the repeat."""
    g = torch.Generator().manual_seed(0)
    t0, t1 = np.arange(0, 60, 1 / 20), np.arange(0.007, 60, 1 / 30)
    p0 = add_noise(torch.from_numpy(_repeating(t0))[:, None], noise, g)[:, 0].numpy()
    p1 = add_noise(torch.from_numpy(_repeating(t1))[:, None], noise, g)[:, 0].numpy()
    with pytest.raises(InputError, match="ambiguous time offset") as err:
        estimate_time_offset(t0, p0, t1 - 1234.5678, p1)
    found, other = (float(x) for x in re.findall(r"at offset ([-+\d.]+) s", str(err.value))[:2])
    repeats = abs(found - other) / (10 * np.pi)  # the two peaks lie a whole number of repeats apart
    assert round(repeats) >= 1 and abs(repeats - round(repeats)) < 0.02


@pytest.mark.parametrize("noise", [0.0, 0.002])
def test_the_rotation_constraint_chooses_among_repeats_of_the_speed(noise):
    """The motion above, whose angular speed repeats but whose rotations do not, on a rig with an extrinsic: the
    speeds alone are ambiguous, the rig's rotation constraint is not, and finds the offset within a fifth of a frame."""
    g = torch.Generator().manual_seed(1)
    X = random_rig(g).numpy()
    t0, t1, offset = np.arange(0, 60, 1 / 30), np.arange(0.007, 60, 1 / 20), 1234.5678
    p0 = add_noise(torch.from_numpy(_repeating(t0))[:, None], noise, g)[:, 0].numpy()
    p1 = add_noise(torch.from_numpy(_repeating(t1) @ X)[:, None], noise, g)[:, 0].numpy()
    with pytest.raises(InputError, match="ambiguous time offset"):
        estimate_time_offset(t0, p0, t1 - offset, p1)
    found, quality = find_time_offset(t0, p0, t1 - offset, p1)
    assert abs(found - offset) < 0.2 * FRAME
    assert quality.residual_ratio > 10  # with noise the speeds correlate better at the wrong lag (0.90 vs 0.89)


def test_rotations_that_repeat_leave_the_offset_ambiguous():
    """Every rotation repeats each 5 s: no constraint can tell the lags 5 s apart, and the answer is an error."""
    t0, t1 = np.arange(0, 40, 1 / 30), np.arange(0.007, 40, 1 / 20)
    periodic = lambda t: np.stack([cv2.Rodrigues(np.array([0.6, 0.5, 0.4]) * np.sin(2 * np.pi * s / 5 + np.array(
        [0.0, 1.0, 2.0])))[0] for s in t])  # noqa: E731  # fmt: skip
    pose = lambda R: np.concatenate([np.concatenate([R, np.zeros((len(R), 3, 1))], 2),
                                     np.tile([[[0.0, 0, 0, 1]]], (len(R), 1, 1))], 1)  # noqa: E731  # fmt: skip
    with pytest.raises(InputError, match="ambiguous time offset .*: their rotations agree about as well at"):
        find_time_offset(t0, pose(periodic(t0)), t1 - 100.0, pose(periodic(t1)))


@pytest.mark.parametrize("seed", [12, 15, 17])
def test_one_peak_broadened_by_pose_noise_is_not_ambiguous(seed):
    """Pose noise 0.002 rad ripples the top of the correlation's one peak into local maxima 0.04-0.08 s apart (on
    these seeds they came within the ambiguity margin): they are one peak, and the offset is found within a
    frame of camera 0 (what the angular speeds give at this noise; refine_time_offset takes it further)."""
    g = torch.Generator().manual_seed(seed)
    X = random_rig(g).numpy()
    t0, t1, offset = np.arange(0, 40, 1 / 20), np.arange(0.007, 40, 1 / 30), 1234.5678
    p0 = add_noise(torch.from_numpy(wobble(t0))[:, None], 0.002, g)[:, 0].numpy()
    p1 = add_noise(torch.from_numpy(wobble(t1, X))[:, None], 0.002, g)[:, 0].numpy()
    found, quality = estimate_time_offset(t0, p0, t1 - offset, p1)
    assert abs(found - offset) < 1 / 20
    assert quality.runner_up < quality.correlation - 0.1  # what lies outside the peak is another lobe of the motion


def test_the_runner_up_lies_outside_the_main_peak():
    """On a correlation curve made by hand: a broad peak with ripples on its top has no runner-up of its own; a
    second peak beyond a dip below half is the runner-up, at its own index."""
    lags = np.arange(2000.0)
    broad = 0.95 * np.exp(-0.5 * ((lags - 600) / 80) ** 2) + 0.01 * np.sin(lags / 3)  # local maxima every ~19 lags
    best = int(np.argmax(broad))
    value, _ = _runner_up(broad, best)
    assert value < 0.95 / 2 + 0.02
    repeated = broad + 0.9 * np.exp(-0.5 * ((lags - 1400) / 80) ** 2)
    value, index = _runner_up(repeated, best)
    assert abs(index - 1400) <= 10 and abs(value - repeated[1400]) < 0.02


def test_offset_flat_angular_speed(rig):
    t0, p0, t1, p1 = rig(0, rotation=0.0)  # pure translation
    with pytest.raises(InputError, match="camera 0: angular speed too flat to estimate a time offset"):
        estimate_time_offset(t0, p0, t1, p1)
    spin = np.tile(np.eye(4), (len(t0), 1, 1))  # constant rate about z
    c, s = np.cos(0.5 * t0), np.sin(0.5 * t0)
    spin[:, 0, 0], spin[:, 0, 1], spin[:, 1, 0], spin[:, 1, 1] = c, -s, s, c
    with pytest.raises(InputError, match="angular speed too flat"):
        estimate_time_offset(t0, spin, t0, spin)


def test_offset_too_few_poses(rig):
    t0, p0, t1, p1 = rig(0, duration=0.2)
    with pytest.raises(InputError, match="at least 10 are needed"):
        estimate_time_offset(t0, p0, t1, p1)


def test_angular_speed_is_mounting_invariant(rig):
    t0, p0, _, _ = rig(0, rate1=30.0)
    _, _, t1, p1 = rig(0, rate0=30.0, rate1=30.0)
    m0, w0 = angular_speed(t0, p0)
    m1, w1 = angular_speed(t1, p1)
    np.testing.assert_allclose(m0, m1)
    np.testing.assert_allclose(w0, w1, atol=1e-9)


def wobble(times: np.ndarray, X: np.ndarray | None = None) -> np.ndarray:
    """Camera-to-world poses (N, 4, 4) of a smooth, non-repeating rotation about three axes (a rig camera mounted
    at X on it, if given)."""
    T = np.tile(np.eye(4), (len(times), 1, 1))
    for P, t in zip(T, times):
        P[:3, :3] = cv2.Rodrigues(
            np.array([0.6 * np.sin(1.1 * t), 0.5 * np.sin(0.99 * t + 1), 0.4 * np.sin(1.56 * t + 2)])
        )[0]
        P[:3, 3] = [2 * np.sin(0.4 * t), np.cos(0.3 * t), 0.3 * t]
    return T if X is None else T @ X


def test_refine_time_offset_by_the_rig_constraint():
    """Noisy poses (0.002 rad / 0.002 per pose), 20 Hz against 30 Hz: from a start 8 ms off (what the angular
    speeds give at this noise), the rotation constraint brings the offset within 1 ms of the truth."""
    g = torch.Generator().manual_seed(0)
    X = random_rig(g).numpy()
    t0, t1, offset = np.arange(0, 40, 1 / 20), np.arange(0.007, 40, 1 / 30), 1234.5678
    p0 = add_noise(torch.from_numpy(wobble(t0))[:, None], 0.002, g)[:, 0].numpy()
    p1 = add_noise(torch.from_numpy(wobble(t1, X))[:, None], 0.002, g)[:, 0].numpy()
    refined = refine_time_offset(t0, p0, t1 - offset, p1, offset + 0.008, radius=0.1)
    assert abs(refined - offset) < 1e-3
    few = slice(0, 12)  # 0.55 s: no 0.5 s motions to compare at any candidate
    assert refine_time_offset(t0[few], p0[few], t1[few] - offset, p1[few], offset + 0.008, radius=0.1) == offset + 0.008
    broken = p0.copy()
    broken[5] = 0  # a zero pose line (singular): counted out, not an error deep in a matrix inverse
    assert abs(refine_time_offset(t0, broken, t1 - offset, p1, offset + 0.008, radius=0.1) - offset) < 1e-3
