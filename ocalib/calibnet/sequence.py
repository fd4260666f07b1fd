"""A sequence opened for ``ocalib calibrate``: two cameras or more, enough frames, its cameras paired in time; its
input errors found before torch is imported, so that they take a fraction of a second."""

from __future__ import annotations

from pathlib import Path

from ocalib.data.layout import open_sequence
from ocalib.data.sequence import Sequence
from ocalib.data.synchronise import own_clocks, synchronise
from ocalib.errors import InputError
from ocalib.frontend import FrontEndOptions

MIN_FRAMES = 10  # frames below which a sequence is too short to calibrate


def open_calibration_sequence(
    path: str | Path,
    cameras: list[str] | None = None,
    intrinsics: str | None = None,
    max_frames: int | None = None,
    time_offset: list[float | str] | None = None,
    frontend: FrontEndOptions = FrontEndOptions(),
    device: str = "cpu",
) -> Sequence:
    """The sequence at ``path`` as :func:`calibrate_images` calibrates it: at least two cameras, at most
    ``max_frames`` frames, and, where the cameras have clocks of their own or ``time_offset`` is given, its frames
    paired in time (:func:`ocalib.data.synchronise.synchronise`).

    time_offset: one value for every camera k >= 1, or one per camera: seconds, or ``"auto"``: estimated from the
    front end's rotations over the frames as they are (a first pass of ``frontend``), as ``calibrate-poses`` does
    from trajectories. Convention: ``t0 = tk + offset``.
    """
    sequence = open_sequence(path, cameras, intrinsics)
    if len(sequence.cameras) < 2:
        raise InputError(
            f"{path}: calibration needs at least two cameras, the sequence has {', '.join(sequence.names)}"
        )
    frames = len(sequence) if max_frames is None else min(len(sequence), max_frames)
    if frames < MIN_FRAMES:
        raise InputError(f"{path}: {frames} frames is too short to calibrate (at least {MIN_FRAMES})")
    if time_offset is None and not own_clocks(sequence):
        return sequence
    from ocalib.calib.poses.pipeline import offset_specs  # here, as the front end: the checks above load no torch
    from ocalib.calibnet.run import estimate_offsets
    from ocalib.data.static import check_motion

    specs = offset_specs(time_offset, len(sequence.cameras) - 1)
    auto, estimates = [s == "auto" for s in specs], [None] * len(sequence.cameras)
    if any(auto):
        check_motion(sequence)
        found, quality = estimate_offsets(sequence, frontend.resolved(), device, min(frames, sequence.common))
        specs = [f if a else s for f, s, a in zip(found, specs, auto)]
        estimates = [None] + [q if a else None for q, a in zip(quality, auto)]
    sequence = synchronise(sequence, [s or 0.0 for s in specs], frames, estimates)
    if len(sequence) < MIN_FRAMES:
        raise InputError(f"{path}: {len(sequence)} frames pair in time, too few to calibrate (at least {MIN_FRAMES})")
    return sequence
