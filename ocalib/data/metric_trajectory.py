"""A metric trajectory (wheel odometry, GNSS, a stereo or visual-inertial system) met with a sequence's frames.

Convention: poses camera-to-world (4, 4), in metres; stamps in seconds on camera 0's clock.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ocalib.data.sequence import Sequence
from ocalib.errors import InputError
from ocalib.io.poses import describe_invalid, pose_validity, read_poses
from ocalib.io.timing import interpolate

INTERPOLATE_GAP = 1.25  # frame periods of the metric trajectory bridged by interpolation (as calibrate-poses)
OWN = "sequence"  # the value naming the sequence's own camera-0 trajectory instead of a file


def read_metric_trajectory(path, sequence: Sequence, frames: int) -> tuple[Sequence, np.ndarray, list[str]]:
    """Camera 0's trajectory in metres at the sequence's first ``frames`` frames -> (the sequence at the frames met,
    its poses (M, 4, 4), warnings).

    From a KITTI file (one pose a frame of camera 0, before any pairing in time: every frame met) or a timestamped
    file (TUM, EuRoC: interpolated at the sequence's timestamps, as ``calibrate-poses`` does, between samples at most
    ``2 INTERPOLATE_GAP`` of its periods apart). Frames outside the trajectory or in its gaps are left out and said in
    a warning. Every problem (no frame met, an invalid pose) is an :class:`InputError` naming the file. ``path``
    :data:`OWN`: the sequence's own camera-0 poses (KITTI raw's OXTS packets, KITTI odometry's poses, a rig folder's
    ``<camera>/poses.txt``), frames without one left out, unless a file has that name.
    """
    if str(path) == OWN and not Path(path).exists():  # a file of that name is a file
        return _own_trajectory(sequence, frames)
    trajectory = read_poses(path)
    keep = np.arange(frames)
    if trajectory.times is None:
        pairing = sequence.pairing
        count = len(sequence) if pairing is None else int(pairing.counts[0])
        if len(trajectory) != count:
            raise InputError(
                f"{path}: {len(trajectory)} poses for the {count} frames of {sequence.path}; a "
                "file without timestamps (KITTI) must hold one pose per frame"
            )
        at = keep if pairing is None else pairing.frames[:frames, 0]  # camera 0's frames kept
        poses, lines = trajectory.poses[at], trajectory.lines[at]
    else:
        if sequence.times is None:
            raise InputError(f"{path}: timestamped poses, but {sequence.path} has no timestamps to meet them at")
        period = float(np.median(np.diff(trajectory.times))) if len(trajectory) > 1 else 0.0
        names = (str(sequence.path), str(path))
        at = sequence.times[:frames]
        keep, poses, idx = interpolate(at, trajectory.times, trajectory.poses, INTERPOLATE_GAP * period, names=names)
        if len(keep) < 2:
            raise InputError(f"{path}: a pose at {len(keep)} of the {frames} frames' timestamps; at least 2 are needed")
        lines = trajectory.lines[idx]
    problem = describe_invalid(path, pose_validity(poses), lines)
    if problem:
        raise InputError(problem)
    warnings = _unmet_warning(path, sequence.times, frames, keep)
    return (sequence if len(keep) == frames else sequence.at(keep)), poses, warnings


def _own_trajectory(sequence: Sequence, frames: int) -> tuple[Sequence, np.ndarray, list[str]]:
    """:func:`read_metric_trajectory` of the sequence's own camera-0 poses."""
    poses = sequence.cameras[0].poses
    if poses is None:
        raise InputError(
            f"{sequence.path}: --metric-trajectory {OWN}: the sequence has no trajectory of its own (KITTI raw's OXTS "
            "packets, KITTI odometry's poses, a rig folder's <camera>/poses.txt); give the trajectory's file"
        )
    keep = np.flatnonzero(np.isfinite(poses[:frames]).all((1, 2)))
    if len(keep) < 2:
        raise InputError(f"{sequence.path}: its own trajectory has a pose at {len(keep)} of the {frames} frames")
    warnings = _unmet_warning(f"{sequence.path}'s own trajectory", sequence.times, frames, keep)
    return (sequence if len(keep) == frames else sequence.at(keep)), poses[keep], warnings


def _unmet_warning(path, times: np.ndarray | None, frames: int, keep: np.ndarray) -> list[str]:
    """The line saying which of the first ``frames`` frames (stamped ``times``, seconds) the trajectory ``path`` did
    not meet (all but ``keep``, (M,) int), and where."""
    if len(keep) == frames:
        return []
    missing = np.setdiff1d(np.arange(frames), keep)
    spans = np.split(missing, np.flatnonzero(np.diff(missing) > 1) + 1)
    span = (
        (lambda s: f"frames {s[0]}-{s[-1]}")
        if times is None
        else (lambda s: f"t = {times[s[0]]:.3f}-{times[s[-1]]:.3f} s")
    )
    where = ", ".join(span(s) for s in spans[:3]) + (", ..." * (len(spans) > 3))
    return [
        f"{path}: no pose at {len(missing)} of the {frames} frames ({where}: outside the trajectory or in its gaps); "
        "those frames are left out"
    ]
