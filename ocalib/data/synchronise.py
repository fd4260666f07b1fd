"""Cameras on clocks of their own, paired into synchronised frames: each frame of camera 0 with the nearest frame of
every other camera in time, after the camera's clock offset. Cameras may drop frames and run at their own rates: a
camera-0 frame without a partner in every camera is skipped and counted, and a gap in a camera's stamps of over
``GAP_PERIODS`` of its frame periods is said in a warning.

Convention: a time offset is ADDED to camera k's stamps to put them on camera 0's clock, ``t0 = tk + offset``;
a pair's residual is ``t0 - (tk + offset)``: what is left of the offset after the nearest frame is taken.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import reduce

import numpy as np

from ocalib.data.sequence import Sequence
from ocalib.errors import InputError
from ocalib.io.timing import associate

GAP_PERIODS = 3  # a camera's stamps further apart than this many of its median frame periods: a gap, warned about


@dataclass(frozen=True)
class Pairing:
    """How a sequence's frames were paired.

    offsets (C,) seconds, 0 for camera 0; frames (M, C) int: each camera's own frame index of every paired frame;
    residuals (M, C) seconds, ``t0 - (tk + offset)``; counts (C,): each camera's frames before pairing;
    estimates: per camera, how an estimated offset scored (:class:`ocalib.calib.drivers.clock.OffsetQuality`),
    else None; skipped (C,) int: camera 0's frames (of those paired) without a partner in camera k (0 for camera 0);
    warnings: the frames skipped and the gaps in the cameras' stamps, one line each.
    """

    offsets: np.ndarray
    frames: np.ndarray
    residuals: np.ndarray
    counts: np.ndarray
    estimates: tuple = ()
    skipped: np.ndarray | None = None
    warnings: tuple[str, ...] = ()

    def at(self, rows: np.ndarray) -> Pairing:
        """The pairing of the paired frames ``rows`` (M',) only (the others left out after pairing)."""
        return replace(self, frames=self.frames[rows], residuals=self.residuals[rows])

    def camera_json(self, k: int) -> dict:
        """Camera k's offset, its pairs and what is left of the offset in them, for the result JSON."""
        r = np.abs(self.residuals[:, k])
        return {
            "time_offset": float(self.offsets[k]),
            "source": "estimated" if k < len(self.estimates) and self.estimates[k] is not None else "given",
            "pairs": len(r),
            "unpaired_frames": int(self.counts[k] - len(r)),
            "skipped_frames": 0 if self.skipped is None else int(self.skipped[k]),
            "pair_residual_median_s": float(np.median(r)),
            "pair_residual_max_s": float(r.max()),
        }


def clocks(sequence: Sequence) -> list[np.ndarray] | None:
    """Every camera's stamps on its own clock (N,) (the sequence's where a camera has none), or None where the
    sequence has no timestamps at all."""
    if sequence.times is None and all(c.times is None for c in sequence.cameras):
        return None
    shared = sequence.times if sequence.times is not None else sequence.cameras[0].times
    return [shared if c.times is None else c.times for c in sequence.cameras]


def own_clocks(sequence: Sequence) -> bool:
    """Whether a camera has stamps of its own: its frames are then paired by time, not by index."""
    return any(c.times is not None for c in sequence.cameras)


def synchronise(sequence: Sequence, offsets, frames: int | None = None, estimates: tuple = ()) -> Sequence:
    """The sequence with each of camera 0's first ``frames`` frames (default all) paired with every camera's nearest
    frame in time, within half camera 0's median frame period; only frames every camera pairs are kept, the others
    skipped (counted, and said in the pairing's warnings with the gaps in the cameras' stamps).

    offsets: (C,) or (C - 1,) seconds, one per camera k >= 1 (camera 0's is 0). The result's cameras have M
    frames each (images, poses, depth, the frame of a change, re-indexed), its ``times`` camera 0's, and its
    ``pairing`` (:class:`Pairing`, with ``estimates``) says how. InputError, naming the cameras, where fewer than two
    frames pair.
    Convention: ``t0 = tk + offset``.
    """
    stamps = clocks(sequence)
    if stamps is None:
        raise InputError(f"{sequence.path}: no timestamps, so no frames to pair in time (a time offset needs them)")
    offsets = np.asarray(offsets, dtype=np.float64)
    offsets = np.concatenate([[0.0], offsets]) if len(offsets) == len(sequence.cameras) - 1 else offsets
    t0 = stamps[0][: frames or len(stamps[0])]
    period = float(np.median(np.diff(t0))) if len(t0) > 1 else 1.0
    names = sequence.names
    pairs = [
        associate(t0, t, period / 2, o, names=(names[0], n)) for t, o, n in zip(stamps[1:], offsets[1:], names[1:])
    ]
    kept = reduce(np.intersect1d, [i0 for i0, _ in pairs], np.arange(len(t0)))
    if len(kept) < 2:
        raise InputError(
            f"{sequence.path}: {len(kept)} frame(s) of {names[0]} pair with a frame of every camera within half a frame "
            f"period ({period / 2:.6g} s) at time offsets {', '.join(f'{o:+.6g} s' for o in offsets[1:])}"
        )
    index = np.stack([kept] + [i1[np.searchsorted(i0, kept)] for i0, i1 in pairs], 1)
    residuals = t0[kept, None] - (np.stack([t[j] for t, j in zip(stamps, index.T)], 1) + offsets)
    cameras = [replace(c.at(index[:, k]), times=None) for k, c in enumerate(sequence.cameras)]  # on camera 0's
    counts = np.array([len(c) for c in sequence.cameras])
    skipped = np.array([0] + [len(t0) - len(i0) for i0, _ in pairs])
    shifted = [t + o for t, o in zip(stamps, offsets)]
    warnings = _skipped_warning(names, t0, kept, skipped) + [
        w for t, n in zip(shifted, names) for w in gap_warnings(t, t0[0], t0[-1], n)
    ]
    pairing = Pairing(offsets, index, residuals, counts, tuple(estimates), skipped, tuple(warnings))
    return replace(sequence, cameras=cameras, times=t0[kept], pairing=pairing)


def gap_warnings(times: np.ndarray, start: float, end: float, name: str, periods: float = GAP_PERIODS) -> list[str]:
    """A line per gap in camera ``name``'s stamps ``times`` (N,) seconds within [start, end] (camera 0's span): two
    consecutive stamps over ``periods`` of the camera's median frame period apart.
    Convention: ``times`` on camera 0's clock (``tk + offset``)."""
    times = times[(times >= start) & (times <= end)]
    if len(times) < 3:
        return []
    step = np.diff(times)
    period = float(np.median(step))
    return [
        f"{name}: no frame from t = {times[i]:.6f} s to {times[i + 1]:.6f} s ({step[i]:.3f} s, {step[i] / period:.1f} "
        f"of its frame periods): a gap in its recording"
        for i in np.flatnonzero(step > periods * period)
    ]


def _skipped_warning(names: list[str], t0: np.ndarray, kept: np.ndarray, skipped: np.ndarray) -> list[str]:
    """The line saying how many of camera 0's frames ``t0`` (N,) were skipped, ``kept`` (M,) kept, and which camera
    lacked a partner for how many (``skipped`` (C,))."""
    if len(kept) == len(t0):
        return []
    lacking = ", ".join(f"{n} {s}" for n, s in zip(names[1:], skipped[1:]) if s)
    return [
        f"{names[0]}: {len(t0) - len(kept)} of its {len(t0)} frames skipped: no frame within half a frame period in "
        f"every camera (frames without a partner: {lacking})"
    ]
