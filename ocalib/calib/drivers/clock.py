"""The clock offset between two cameras of one rig, from their motion alone: the angular speeds cross-correlated
(:func:`estimate_time_offset`), then refined by the rig's hand-eye rotation constraint (:func:`refine_time_offset`).

Convention: a time offset is ADDED to camera 1's timestamps to put them on camera 0's clock,
``t0 = t1 + offset``; poses camera-to-world, times strictly increasing seconds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ocalib.calib.stages.handeye import rotation_block
from ocalib.errors import InputError
from ocalib.geometry import rotation_angle
from ocalib.geometry.pose import invert_pose
from ocalib.geometry.quaternion import rotation_matrix_to_quaternion
from ocalib.io.poses import pose_validity
from ocalib.io.timing import INTERPOLATION_MAX_DT_PERIODS, increasing, interpolate

# estimate_time_offset: lags overlapping less than MIN_OVERLAP of the shorter recording are not
# considered (short overlaps give spurious peaks). The answer is an error rather than a guess when its
# normalised correlation is below MIN_CORRELATION, or when another lag (outside the peak: see _runner_up) comes
# close: 1 - runner_up < max(MIN_DISTINCTNESS * (1 - correlation), MIN_SEPARATION). The floor matters for clean,
# repetitive motion: two lags can both correlate to within 1e-5 of perfect, and the better of them by a hair need
# not be the right one (measured: a smooth test motion whose rotation vector repeats with a sign flip every 31.4 s;
# the wrong lag scored 0.9999995, the right one 0.999995).
MIN_OVERLAP = 0.3
MIN_CORRELATION = 0.5
MIN_DISTINCTNESS = 2.0
MIN_SEPARATION = 1e-3
MIN_MOTIONS = 10
# find_time_offset: the correlation's peaks the rig's rotation constraint chooses among, and how many times lower
# the chosen one's rotation residual must be than any other's
CANDIDATES = 5
MIN_RESIDUAL_RATIO = 2.0
REFINE_MOTION_SECONDS = 0.5  # refine_time_offset: the length of the motions compared (longer: a lag shows more)


def angular_speed(times, poses) -> tuple[np.ndarray, np.ndarray]:
    """Rotation speed of consecutive valid poses -> (mid times (M,), speed (M,) in rad/s).

    times (N,) seconds, poses (N, 4, 4) camera-to-world; invalid poses (see ``pose_validity``) are
    skipped. The speed is the same for every camera of a rigid rig, whatever its mounting.
    """
    times = np.asarray(times, dtype=np.float64)
    poses = np.asarray(poses, dtype=np.float64)
    ok = pose_validity(poses)
    times, R = times[ok], torch.from_numpy(poses[ok, :3, :3])
    angle = rotation_angle(R[:-1].mT @ R[1:]).numpy()
    return (times[1:] + times[:-1]) / 2, angle / np.diff(times)


@dataclass(frozen=True)
class OffsetQuality:
    """How trustworthy an estimated time offset is.

    correlation: normalised cross-correlation of the two angular speeds at the offset, in [-1, 1].
    runner_up: the best correlation at any other offset (outside the peak's lobe); periodic motion or
    unrelated recordings bring it close to ``correlation``. overlap: seconds of motion the two cameras
    share at the offset. step: seconds between samples of the coarse correlation grid.
    angular_speed_offset: set where the offset was then refined (:func:`refine_time_offset`).
    residual_ratio: set by :func:`find_time_offset`: how much worse the rotations agree at the next candidate offset
    (inf: no other candidate).
    """

    correlation: float
    runner_up: float
    overlap: float
    step: float
    angular_speed_offset: float | None = None  # the correlation's own answer, before a refinement (if any)
    residual_ratio: float | None = None  # find_time_offset: the next candidate's rotation residual over the chosen's


def estimate_time_offset(times0, poses0, times1, poses1, names=("camera 0", "camera 1")):
    """Clock offset between two cameras of one rig -> (offset seconds, OffsetQuality).

    times0 (N0,), poses0 (N0, 4, 4), times1 (N1,), poses1 (N1, 4, 4): each camera on its own clock, any
    rates; the offset may be arbitrarily large (Unix time against time since boot). Cross-correlates the
    cameras' angular speeds: both are resampled on uniform grids of one step, every lag is scored by
    FFT with the normalised correlation over the overlap, and the best is refined by a fine local search
    with parabolic interpolation, to well below a frame period. InputError when the angular speed is
    flat (no rotation), or the peak is weak or ambiguous (see MIN_CORRELATION, MIN_DISTINCTNESS).
    Convention: ``t0 = t1 + offset`` (ADD the offset to times1).
    """
    xc = _correlation(times0, poses0, times1, poses1, names)
    g0, x, m0, m1, w1, ncc, step = xc.g0, xc.x, xc.m0, xc.m1, xc.w1, xc.ncc, xc.step
    best = int(np.argmax(ncc))
    runner_up, second = _runner_up(ncc, best)
    coarse = xc.offsets[best]

    # Fine search: correlate the camera-0 grid with camera 1's speed interpolated at the shifted times.
    fine = coarse + np.linspace(-step, step, 21)
    scores = np.array([_ncc_at(g0, x, m1, w1, tau) for tau in fine])
    k = int(np.argmax(scores))
    offset, peak = fine[k], scores[k]
    if 0 < k < len(fine) - 1:
        a, b, c = scores[k - 1 : k + 2]
        curvature = a - 2 * b + c
        if curvature < 0:
            delta = 0.5 * (a - c) / curvature
            offset += delta * (fine[1] - fine[0])
            peak = b - 0.25 * (a - c) * delta
    peak = min(peak, 1.0)
    overlap = min(m0[-1], m1[-1] + offset) - max(m0[0], m1[0] + offset)
    found = f"{peak:.3f} at offset {offset:+.6f} s (over {overlap:.1f} s)"
    if not peak >= MIN_CORRELATION:
        raise InputError(
            f"no clear time offset between {names[0]} and {names[1]}: the best normalised correlation of their "
            f"angular speeds is {found}, below {MIN_CORRELATION}. The recordings may share too little time (at "
            f"least {MIN_OVERLAP:.0%} of the shorter one is needed) or not show the same motion; "
            "give --time-offset SECONDS"
        )
    if 1 - runner_up < max(MIN_DISTINCTNESS * (1 - peak), MIN_SEPARATION):
        other = xc.offsets[second]
        raise InputError(
            f"ambiguous time offset between {names[0]} and {names[1]}: the normalised correlation of their angular "
            f"speeds is {found}, but {runner_up:.3f} at offset {other:+.6f} s. The motion may be repetitive or the "
            f"recordings may share too little time (at least {MIN_OVERLAP:.0%} of the shorter one is needed); "
            "give --time-offset SECONDS"
        )
    return float(offset), OffsetQuality(float(peak), runner_up, float(overlap), float(step))


def refine_time_offset(
    times0,
    poses0,
    times1,
    poses1,
    offset: float,
    radius: float,
    steps: int = 21,
    motion_seconds: float = REFINE_MOTION_SECONDS,
) -> float:
    """Refine a clock offset by the rig's own rotation constraint -> offset (s).

    The rotation residual (:func:`rotation_residual`) is least at the true offset; it is scored at ``steps``
    candidates in ``offset +- radius``. A lag
    ``d`` leaves each pair of motions differing by about ``(w(t + T) - w(t)) d`` (angular velocity ``w``,
    motion length ``T``): unlike the angular speed, this sees the axes too, and is not biased by the noise of
    short motions. The best candidate is refined by a parabola through its neighbours; with too few motions at
    every candidate the offset comes back as it was. Convention:
    ``t0 = t1 + offset``; poses camera-to-world, times strictly increasing seconds.
    """
    candidates = offset + np.linspace(-radius, radius, steps)
    scores = np.array([rotation_residual(times0, poses0, times1, poses1, c, motion_seconds) for c in candidates])
    if not np.isfinite(scores).any():  # too few motions at every candidate: nothing to refine with
        return float(offset)
    k = int(np.argmin(scores))
    best = float(candidates[k])
    if 0 < k < steps - 1 and np.isfinite(scores[k - 1 : k + 2]).all():
        a, b, c = scores[k - 1 : k + 2]
        curvature = a - 2 * b + c
        if curvature > 0:
            best += 0.5 * (a - c) / curvature * (candidates[1] - candidates[0])
    return best


def rotation_residual(times0, poses0, times1, poses1, offset: float, motion_seconds=REFINE_MOTION_SECONDS) -> float:
    """How far the two cameras' rotations are from a rigid rig's at clock offset ``offset`` (inf: too few motions).

    Camera 1 is interpolated at camera 0's stamps (:func:`interpolate`); the motions of both cameras over
    ``motion_seconds`` give the hand-eye rotation blocks ``A = L(q0) - R(q1)``, and a rigid rig has a rotation ``dq``
    with ``A dq = 0`` for all of them: the smallest eigenvalue of their mean Gram matrix (the residual of the best
    ``dq``) is returned. Convention: ``t0 = t1 + offset``; poses camera-to-world, times strictly increasing seconds.
    """
    poses0 = np.asarray(poses0, dtype=np.float64)
    period = float(np.median(np.diff(times1)))
    gap = max(1, int(round(motion_seconds / float(np.median(np.diff(times0))))))
    try:
        i0, p1, _ = interpolate(times0, times1, poses1, INTERPOLATION_MAX_DT_PERIODS * period, offset)
    except InputError:
        return np.inf
    p0, p1 = torch.from_numpy(poses0[i0]), torch.from_numpy(p1)
    same = torch.from_numpy(np.flatnonzero(i0[gap:] - i0[:-gap] == gap))  # over consecutive camera-0 frames
    m0 = (invert_pose(p0[same]) @ p0[same + gap]).numpy()  # rigid inverse: garbage poses give garbage, not errors
    m1 = (invert_pose(p1[same]) @ p1[same + gap]).numpy()
    ok = pose_validity(m0) & pose_validity(m1)
    if ok.sum() < MIN_MOTIONS:
        return np.inf
    q0 = rotation_matrix_to_quaternion(torch.from_numpy(m0[ok, :3, :3]))
    A = rotation_block(q0, rotation_matrix_to_quaternion(torch.from_numpy(m1[ok, :3, :3])))
    return float(torch.linalg.eigvalsh((A.mT @ A).mean(0))[0])


def find_time_offset(times0, poses0, times1, poses1, names=("camera 0", "camera 1")) -> tuple[float, OffsetQuality]:
    """Clock offset between two cameras of one rig, to well below a frame -> (offset seconds, OffsetQuality).

    The angular speeds' correlation (as :func:`estimate_time_offset`) proposes its ``CANDIDATES`` highest peaks
    (each at least ``MIN_CORRELATION``); each is refined by the rig's rotation constraint within two frame periods
    (:func:`refine_time_offset`), and the one whose rotations agree best (:func:`rotation_residual`) is the answer.
    Unlike the speed, the constraint sees the rotation axes: a walker's steps repeat the speed, not the rotations.
    InputError where the speed is flat, no peak is strong enough, or another candidate's residual is within
    ``MIN_RESIDUAL_RATIO`` of the best's. Shapes as :func:`estimate_time_offset`. Convention: ``t0 = t1 + offset``.
    """
    c = _correlation(times0, poses0, times1, poses1, names)
    period = max(float(np.median(np.diff(t))) for t in (times0, times1))
    peaks = _peaks(c.ncc, max(1, int(2 * period / c.step)))
    if not len(peaks):
        raise InputError(
            f"no clear time offset between {names[0]} and {names[1]}: the normalised correlation of their angular "
            f"speeds is at most {np.max(c.ncc):.3f}, below {MIN_CORRELATION}; give --time-offset SECONDS"
        )
    refined = [refine_time_offset(times0, poses0, times1, poses1, c.offsets[i], 2 * period) for i in peaks]
    residuals = np.array([rotation_residual(times0, poses0, times1, poses1, o) for o in refined])
    order = np.argsort(residuals)
    best = order[0]
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = float(residuals[order[1]] / residuals[best]) if len(order) > 1 else np.inf
    if not ratio >= MIN_RESIDUAL_RATIO:
        second = order[1]
        raise InputError(
            f"ambiguous time offset between {names[0]} and {names[1]}: their rotations agree about as well at "
            f"{refined[best]:+.6f} s (residual {residuals[best]:.3g}) as at {refined[second]:+.6f} s "
            f"({residuals[second]:.3g}); the motion may be repetitive; give --time-offset SECONDS"
        )
    runner_up, _ = _runner_up(c.ncc, peaks[best])
    overlap = min(c.m0[-1], c.m1[-1] + refined[best]) - max(c.m0[0], c.m1[0] + refined[best])
    quality = OffsetQuality(float(c.ncc[peaks[best]]), runner_up, overlap, c.step, c.offsets[peaks[best]], ratio)
    return float(refined[best]), quality


@dataclass(frozen=True)
class _Correlation:
    """The angular speeds' normalised correlation over lags: ``offsets`` (L,) seconds and ``ncc`` (L,) (-inf where
    the overlap is too short), the speeds (camera 0 on its grid ``g0``: ``x``; camera 1 as sampled: ``m1``, ``w1``;
    ``m0`` camera 0's sample times), the grid's ``step``."""

    offsets: np.ndarray
    ncc: np.ndarray
    step: float
    g0: np.ndarray
    x: np.ndarray
    m0: np.ndarray
    m1: np.ndarray
    w1: np.ndarray


def _correlation(times0, poses0, times1, poses1, names) -> _Correlation:
    """Both angular speeds resampled on uniform grids of one step, every lag scored by FFT with the normalised
    correlation over the overlap."""
    m0, w0 = _speed_signal(times0, poses0, names[0])
    m1, w1 = _speed_signal(times1, poses1, names[1])
    step = min(np.median(np.diff(m0)), np.median(np.diff(m1))) / 2
    step = max(step, max(m0[-1] - m0[0], m1[-1] - m1[0]) / 2**20)  # bounds the FFT size
    g0 = m0[0] + step * np.arange(int((m0[-1] - m0[0]) / step) + 1)
    g1 = m1[0] + step * np.arange(int((m1[-1] - m1[0]) / step) + 1)
    x, y = np.interp(g0, m0, w0), np.interp(g1, m1, w1)
    lags, ncc, counts = _normalised_xcorr(x, y)
    ncc[counts < MIN_OVERLAP * min(len(x), len(y))] = -np.inf
    return _Correlation(g0[0] - g1[0] + lags * step, ncc, float(step), g0, x, m0, m1, w1)


def _peaks(ncc: np.ndarray, separation: int) -> np.ndarray:
    """Indices of the ``CANDIDATES`` highest local maxima of ``ncc`` at least ``MIN_CORRELATION``, each at least
    ``separation`` samples from a higher one."""
    inner = (ncc[1:-1] >= ncc[:-2]) & (ncc[1:-1] >= ncc[2:]) & (ncc[1:-1] >= MIN_CORRELATION)
    chosen: list[int] = []
    for i in np.flatnonzero(inner)[np.argsort(-ncc[1:-1][inner])] + 1:
        if all(abs(i - j) >= separation for j in chosen):
            chosen.append(int(i))
        if len(chosen) == CANDIDATES:
            break
    return np.asarray(chosen, dtype=int)


def _speed_signal(times, poses, name: str):
    times = increasing(times, name)
    if np.shape(poses) != (len(times), 4, 4):
        raise InputError(f"{name}: {len(times)} timestamps but poses of shape {np.shape(poses)}")
    m, w = angular_speed(times, poses)
    if len(m) < MIN_MOTIONS:
        raise InputError(
            f"{name}: {len(m)} motions between valid poses, at least {MIN_MOTIONS} are needed to estimate a time offset"
        )
    if np.std(w) <= 1e-3 * max(np.mean(w), 1.0):
        raise InputError(
            f"{name}: angular speed too flat to estimate a time offset "
            f"(mean {np.mean(w):.3g} rad/s, std {np.std(w):.2g} rad/s); give --time-offset SECONDS"
        )
    return m, w


def _normalised_xcorr(x: np.ndarray, y: np.ndarray):
    """Normalised correlation of x[i] with y[i - k] over their overlap, for every lag k.

    -> lags (L,), ncc (L,), overlap counts (L,), with k from -(len(y) - 1) to len(x) - 1.
    """
    n0, n1 = len(x), len(y)
    x, y = x - x.mean(), y - y.mean()
    n = 1 << int(np.ceil(np.log2(n0 + n1 - 1)))
    circular = np.fft.irfft(np.fft.rfft(x, n) * np.conj(np.fft.rfft(y, n)), n)
    lags = np.arange(-(n1 - 1), n0)
    sxy = circular[lags % n]
    lo0, hi0 = np.maximum(0, lags), np.minimum(n0, n1 + lags)
    lo1, hi1 = lo0 - lags, hi0 - lags
    cx, cxx = np.r_[0, np.cumsum(x)], np.r_[0, np.cumsum(x * x)]
    cy, cyy = np.r_[0, np.cumsum(y)], np.r_[0, np.cumsum(y * y)]
    count = hi0 - lo0
    sx, sxx = cx[hi0] - cx[lo0], cxx[hi0] - cxx[lo0]
    sy, syy = cy[hi1] - cy[lo1], cyy[hi1] - cyy[lo1]
    var = (sxx - sx * sx / count) * (syy - sy * sy / count)
    tiny = var <= 1e-12 * (sxx * syy).clip(1e-300)
    ncc = np.where(tiny, -np.inf, (sxy - sx * sy / count) / np.sqrt(np.where(tiny, 1.0, var)))
    return lags, ncc, count


def _runner_up(ncc: np.ndarray, best: int) -> tuple[float, int]:
    """Highest score and its index outside the main peak. The peak spans, each side of ``best``, the lags down to
    the first valley and all lags on to where the correlation first falls below half the peak's: pose noise
    ripples the top of one broad peak into local maxima a few samples apart, which are that peak, not a repeat (a
    repeating motion's second peak lies beyond a dip below half)."""
    scores = np.maximum(ncc, -2.0)
    right, left = scores[best:], scores[best::-1]  # from the peak outwards

    def extent(side: np.ndarray) -> int:
        """Samples from the peak to the farther of its first valley and its first score below half the peak's."""
        rising = np.flatnonzero(np.diff(side) > 0)
        below = np.flatnonzero(side < side[0] / 2)
        end = len(side) - 1  # the last lag: the peak runs to the end of the lags
        return max(rising[0] if len(rising) else end, below[0] if len(below) else end)

    hi, lo = best + extent(right), best - extent(left)
    outside = np.r_[ncc[:lo], ncc[hi + 1 :]]
    if not len(outside):
        return -np.inf, best
    k = int(np.argmax(outside))
    return float(outside[k]), k if k < lo else k - lo + hi + 1


def _ncc_at(g0, x, m1, w1, offset) -> float:
    """Normalised correlation of x on grid g0 with camera 1's speed (m1, w1) shifted by offset."""
    inside = (g0 >= m1[0] + offset) & (g0 <= m1[-1] + offset)
    if inside.sum() < 3:
        return -np.inf
    a = x[inside] - x[inside].mean()
    b = np.interp(g0[inside] - offset, m1, w1)
    b = b - b.mean()
    denom = np.sqrt((a @ a) * (b @ b))
    return float(a @ b / denom) if denom > 0 else -np.inf
