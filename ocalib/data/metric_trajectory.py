"""A metric trajectory (wheel odometry, GNSS, a stereo or visual-inertial system) met with a sequence's frames.

Convention: poses camera-to-world (4, 4), in metres.
"""

from __future__ import annotations

import numpy as np

from ocalib.data.sequence import Sequence
from ocalib.errors import InputError
from ocalib.io.poses import describe_invalid, pose_validity, read_poses
from ocalib.io.timing import interpolate

INTERPOLATE_GAP = 1.25  # frame periods of the metric trajectory bridged by interpolation (as calibrate-poses)


def read_metric_trajectory(path, sequence: Sequence, frames: int) -> np.ndarray:
    """Camera 0's trajectory in metres at the sequence's first ``frames`` frames (frames, 4, 4), from a KITTI file
    (one pose a frame of camera 0, before any pairing in time) or a timestamped file (TUM, EuRoC: interpolated at the
    sequence's timestamps, as ``calibrate-poses`` does). Every problem is an :class:`InputError` naming the file."""
    trajectory = read_poses(path)
    if trajectory.times is None:
        pairing = sequence.pairing
        count = len(sequence) if pairing is None else int(pairing.counts[0])
        if len(trajectory) != count:
            raise InputError(
                f"{path}: {len(trajectory)} poses for the {count} frames of {sequence.path}; a "
                "file without timestamps (KITTI) must hold one pose per frame"
            )
        at = np.arange(frames) if pairing is None else pairing.frames[:frames, 0]  # camera 0's frames kept
        poses, lines = trajectory.poses[at], trajectory.lines[at]
    else:
        if sequence.times is None:
            raise InputError(f"{path}: timestamped poses, but {sequence.path} has no timestamps to meet them at")
        period = float(np.median(np.diff(trajectory.times))) if len(trajectory) > 1 else 0.0
        keep, poses, idx = interpolate(
            sequence.times[:frames],
            trajectory.times,
            trajectory.poses,
            INTERPOLATE_GAP * period,
            names=(str(sequence.path), str(path)),
        )
        if len(keep) < frames:
            missing = np.setdiff1d(np.arange(frames), keep)
            raise InputError(
                f"{path}: no pose at {len(missing)} of the {frames} frames' timestamps (first: frame "
                f"{missing[0]}, t = {sequence.times[missing[0]]:.6f} s)"
            )
        lines = trajectory.lines[idx]
    problem = describe_invalid(path, pose_validity(poses), lines)
    if problem:
        raise InputError(problem)
    return poses
