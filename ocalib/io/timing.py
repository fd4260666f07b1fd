"""Timestamps of cameras on one rig: association (nearest stamp, or interpolation) under a known clock offset
(:mod:`ocalib.calib.drivers.clock` estimates it).

Convention: a time offset is ADDED to camera 1's timestamps to put them on camera 0's clock,
``t0 = t1 + offset``.
"""

from __future__ import annotations

import numpy as np

from ocalib.errors import InputError
from ocalib.io.poses import pose_validity

# interpolate's default max_dt, in camera-k frame periods: a gap of one dropped frame (2 periods) is bridged, two are not
INTERPOLATION_MAX_DT_PERIODS = 1.25


def associate(times0, times1, max_dt: float, offset: float = 0.0, names=("camera 0", "camera 1")):
    """Pair each camera-0 timestamp with the nearest camera-1 timestamp -> (idx0, idx1), int (M,) each.

    times0 (N0,), times1 (N1,): strictly increasing seconds. Pairs with ``|t0 - (t1 + offset)| > max_dt``
    are dropped; a camera-1 stamp nearest to several camera-0 stamps keeps only the closest, so the
    pairing is one-to-one and both index arrays are strictly increasing. O(N log N).
    names: how errors call the two inputs (e.g. their files).
    Convention: ``t0 = t1 + offset``.
    """
    t0 = increasing(times0, names[0])
    t1 = increasing(times1, names[1]) + offset
    if not max_dt >= 0:
        raise InputError(f"max_dt must be >= 0 seconds, got {max_dt}")
    right = np.searchsorted(t1, t0).clip(0, len(t1) - 1)
    left = (right - 1).clip(0)
    j = np.where(np.abs(t0 - t1[left]) <= np.abs(t1[right] - t0), left, right)
    dt = np.abs(t0 - t1[j])
    i = np.flatnonzero(dt <= max_dt)
    if not len(i):
        raise InputError(_no_pairs_message(t0, t1, offset, max_dt, dt.min(), names))
    j, dt = j[i], dt[i]
    order = np.lexsort((dt, j))  # by camera-1 index, closest first
    first = np.r_[True, j[order][1:] != j[order][:-1]]
    keep = order[first]
    return i[keep], j[keep]


def interpolate(times0, times1, poses1, max_dt: float, offset: float = 0.0, names=("camera 0", "camera 1")):
    """Camera 1's poses at camera 0's timestamps -> (idx0 (M,), poses (M, 4, 4), idx1 (M,)).

    Each camera-0 stamp ``t`` between two camera-1 samples ``a <= t <= b`` (their stamps shifted by ``offset``)
    gets the rotation interpolated along the shorter arc (SLERP, :meth:`kornia.geometry.quaternion.Quaternion.slerp`)
    and the position linearly, both at ``u = (t - t_a) / (t_b - t_a)``: exact for a constant angular and linear
    velocity between the samples. A stamp on a sample takes that sample as it is. Stamps outside camera 1's span,
    or between samples more than ``2 max_dt`` apart (a gap in camera 1's recording), are dropped. Where a sample
    used (``u`` not 0 or 1 toward it) is invalid (non-finite or a non-orthonormal rotation), the pose is NaN, so
    that it is counted as invalid downstream; ``idx1`` is then that sample's index, else the nearer sample's (for
    messages).
    times0 (N0,), times1 (N1,) strictly increasing seconds; poses1 (N1, 4, 4) camera-to-world.
    Convention: ``t0 = t1 + offset``.
    """
    import torch  # here, as kornia: associating stamps loads neither
    from kornia.geometry.quaternion import Quaternion  # importing kornia takes 0.2 s, KITTI input never needs it

    from ocalib.geometry.quaternion import quaternion_to_rotation_matrix, rotation_matrix_to_quaternion

    t0 = increasing(times0, names[0])
    t1 = increasing(times1, names[1]) + offset
    if not max_dt >= 0:
        raise InputError(f"max_dt must be >= 0 seconds, got {max_dt}")
    if len(t1) < 2:
        raise InputError(f"{names[1]}: {len(t1)} pose(s): interpolation needs at least 2")
    b = np.searchsorted(t1, t0).clip(1, len(t1) - 1)
    a = b - 1
    before, after = t0 - t1[a], t1[b] - t0
    on_sample = (before == 0) | (after == 0)
    keep = np.flatnonzero((before >= 0) & (after >= 0) & (on_sample | (before + after <= 2 * max_dt)))
    if not len(keep):
        inside = (before >= 0) & (after >= 0)
        gap = (before + after)[inside].min() if inside.any() else np.inf
        rule = f"no {names[0]} stamp between two {names[1]} samples at most 2 max_dt = {2 * max_dt:.6g} s apart"
        raise InputError(_no_pairs_message(t0, t1, offset, max_dt, gap, names, rule))
    a, b, u = a[keep], b[keep], before[keep] / (t1[b[keep]] - t1[a[keep]])
    poses1 = np.asarray(poses1, dtype=np.float64)
    valid = pose_validity(poses1)
    pa, pb = torch.from_numpy(poses1[a]), torch.from_numpy(poses1[b])
    ok_a, ok_b = torch.from_numpy(valid[a]), torch.from_numpy(valid[b])
    eye = torch.eye(3, dtype=torch.float64)
    qa = rotation_matrix_to_quaternion(torch.where(ok_a[:, None, None], pa[:, :3, :3], eye))
    qb = rotation_matrix_to_quaternion(torch.where(ok_b[:, None, None], pb[:, :3, :3], eye))
    w = torch.from_numpy(u)
    out = torch.zeros_like(pa)
    out[:, :3, :3] = quaternion_to_rotation_matrix(Quaternion(qa).slerp(Quaternion(qb), w).data)
    out[:, :3, 3] = (1 - w[:, None]) * pa[:, :3, 3] + w[:, None] * pb[:, :3, 3]
    out[:, 3, 3] = 1
    out = torch.where((w == 0)[:, None, None], pa, torch.where((w == 1)[:, None, None], pb, out))  # samples as they are
    bad_a, bad_b = ~valid[a] & (u < 1), ~valid[b] & (u > 0)
    poses = np.where((bad_a | bad_b)[:, None, None], np.nan, out.numpy())
    idx1 = np.where(bad_a, a, np.where(bad_b, b, np.where(u <= 0.5, a, b)))
    return keep, poses, idx1


def _no_pairs_message(t0, t1, offset, max_dt, closest, names, rule: str | None = None) -> str:
    """Why no camera-0 stamp found a camera-1 pose: the ranges never overlap, or ``rule`` (default: the nearest
    stamp within max_dt) failed everywhere; ``closest`` says by how much."""
    shift = f" (with time offset {offset:+.6f} s)" if offset else ""
    spans = f"{names[0]} spans [{t0[0]:.6f}, {t0[-1]:.6f}] s, {names[1]} spans [{t1[0]:.6f}, {t1[-1]:.6f}] s{shift}"
    if t1[0] > t0[-1] or t1[-1] < t0[0]:
        gap = max(t1[0] - t0[-1], t0[0] - t1[-1])
        return (
            f"no timestamps to pair: {spans}; the time ranges never overlap (gap {gap:.6f} s). "
            "If the cameras' clocks differ, use --time-offset auto (or give the offset in seconds)"
        )
    rule = rule or f"no timestamp pair within max_dt = {max_dt} s"
    return f"{rule}: {spans}; the closest is {closest:.6f} s"


def increasing(times, name: str) -> np.ndarray:
    times = np.asarray(times, dtype=np.float64)
    if times.ndim != 1 or not len(times):
        raise InputError(f"{name}: expected a non-empty 1-D array of timestamps, got shape {times.shape}")
    if not (np.isfinite(times).all() and (np.diff(times) > 0).all()):
        raise InputError(f"{name}: timestamps must be finite and strictly increasing")
    return times
