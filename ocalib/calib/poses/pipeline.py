"""Rig calibration from pose files: the engine of ``ocalib calibrate-poses``.

:func:`load_rig` reads one pose file per camera (KITTI or TUM), puts the cameras on camera 0's clock
and pairs their poses into synchronised frames; :func:`calibrate_rig` streams the frames through the
on-line head (:class:`~ocalib.calib.drivers.online.OnlineCalibrator`), or solves them at once (``batch``), and
returns a :class:`CalibrationRun` with the per-frame estimates, the result JSON and warnings.

Convention: poses camera-to-world (each camera in its own world and units: only motions are used);
the result is ``T_cam0_camk`` (``p_cam0 = R p_camk + t``, camera-0 units) and the scale that multiplies
camera-k units into camera-0 units; a time offset is ADDED to camera k's timestamps (``t0 = tk + offset``).
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass, field, fields, replace
from functools import cached_property, reduce
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from ocalib.calib.drivers.absolute import AbsoluteCalibrator
from ocalib.calib.drivers.batch import batch_calibrate
from ocalib.calib.drivers.change import ChangeTest, first_change, step_size
from ocalib.calib.drivers.clock import find_time_offset
from ocalib.calib.drivers.online import OnlineCalibrator
from ocalib.calib.drivers.options import HeadOptions
from ocalib.calib.drivers.result import Calibration
from ocalib.calib.drivers.sequence import calibrate_sequence
from ocalib.calib.poses.report import (
    CalibrationRun,
    progress_text,
    run_warnings,
    stack_estimates,
    trace_rows,
    untested_warnings,
)
from ocalib.calib.stages.gating import Gates
from ocalib.calib.stages.handeye import row_statistics
from ocalib.calib.stages.planar import planar_axis
from ocalib.calib.stages.rotation import (
    batch_rotation,
    planar_motion,
    rotation_observable,
)
from ocalib.errors import InputError
from ocalib.geometry import quaternion_to_rotation_matrix
from ocalib.io.poses import POSE_TOLERANCE, pose_validity, read_poses
from ocalib.io.timing import INTERPOLATION_MAX_DT_PERIODS, associate, interpolate

MIN_FRAMES = 3  # synchronised frames with every pose valid, below which there is nothing to calibrate
PROGRESS_EVERY = 100  # frames between progress-bar updates (and between copies of the per-frame estimates)
TRACE_CHUNK = 4096  # frames whose uncertainty is computed at once
SYNC_MODES = ("interpolate", "nearest")  # how timestamped cameras meet camera 0's stamps (see load_rig)


@dataclass
class RigPoses:
    """The synchronised poses of a rig of C cameras over T frames.

    files: (C,) the pose files, camera 0 first. poses: (T, C, 4, 4) float64 camera-to-world.
    times: (T,) camera-0 seconds, or None (KITTI without times). lines: (T, C) the file line of each pose.
    time_offsets: (C,) seconds added to camera k's clock (0 for camera 0), None without timestamps.
    offset_quality: per camera, the ``OffsetQuality`` of an estimated (``auto``) offset, else None.
    max_dt: the association tolerance used, seconds (the largest over the cameras; None without timestamps).
    unpaired: per camera k >= 1, the camera-0 stamps inside camera k's time span that found no camera-k pose (its
        gaps, beyond max_dt); empty without timestamps.
    """

    files: list[str]
    poses: np.ndarray
    times: np.ndarray | None
    lines: np.ndarray
    time_offsets: list[float | None]
    offset_quality: list = field(default_factory=list)
    max_dt: float | None = None
    unpaired: list[int] = field(default_factory=list)

    @cached_property
    def valid(self) -> np.ndarray:
        """(T, C) bool: finite pose with an orthonormal rotation (computed once: the poses are not changed)."""
        return np.stack([pose_validity(self.poses[:, c], POSE_TOLERANCE) for c in range(len(self.files))], 1)


def load_rig(
    files: list[str | Path],
    format: str = "auto",
    times: list[str | Path] | None = None,
    time_offset: list[float | str] | None = None,
    max_dt: float | None = None,
    sync: str = "interpolate",
) -> RigPoses:
    """Read C >= 2 pose files and pair their poses into synchronised frames.

    Args:
        files: pose files, camera 0 (the reference) first. format: ``auto``, ``kitti`` or ``tum``.
        times: KITTI ``times.txt`` files, one per pose file (TUM files carry their own timestamps).
        time_offset: one value for every camera k >= 1, or one per camera: seconds, or ``"auto"``
            (estimated by cross-correlating angular speeds). Needs timestamps.
        max_dt: association tolerance in seconds: ``nearest``: the largest distance from a camera-0 stamp to the
            camera-k stamp paired with it, default half camera 0's median frame period; ``interpolate``: half the
            longest gap between camera-k samples to interpolate across, default 1.25 camera-k median frame periods
            (one dropped frame is bridged, two are not).
        sync: with timestamps, how camera k's poses meet camera 0's stamps: ``interpolate`` (SLERP and linear
            between the two samples around each stamp, see :func:`~ocalib.io.timing.interpolate`) or ``nearest``
            (the nearest sample, one-to-one).

    Without timestamps the files must hold one pose per frame (equal lengths). With timestamps every
    camera is brought to camera 0's stamps (``sync``) and only frames that every camera has are kept.
    Raises InputError naming the file (and line) on any bad input.
    """
    if sync not in SYNC_MODES:
        raise InputError(f"unknown sync {sync!r}: {', '.join(SYNC_MODES)}")
    files = [str(f) for f in files]
    if len(files) < 2:
        raise InputError(f"a rig needs at least 2 pose files (camera 0 and one more), got {len(files)}")
    if times is not None and len(times) != len(files):
        raise InputError(f"--times: {len(times)} times files for {len(files)} pose files; give one per pose file")
    trajs = [read_poses(f, format, None if times is None else times[c]) for c, f in enumerate(files)]
    offsets = offset_specs(time_offset, len(files) - 1)
    timed = [t.times is not None for t in trajs]

    if not any(timed):
        if time_offset is not None:
            raise InputError(f"--time-offset needs timestamps: {files[0]} has none (KITTI); give TUM files or --times")
        for f, t in zip(files[1:], trajs[1:]):
            if len(t) != len(trajs[0]):
                raise InputError(
                    f"unequal lengths: {files[0]} has {len(trajs[0])} poses but {f} has {len(t)}; without "
                    "timestamps (KITTI) the files must hold one pose per frame. Give --times to pair poses by time"
                )
        rig = RigPoses(files, np.stack([t.poses for t in trajs], 1), None, np.stack([t.lines for t in trajs], 1),
                       [None] * len(files), [None] * len(files))  # fmt: skip
    elif not all(timed):
        missing = ", ".join(f for f, ok in zip(files, timed) if not ok)
        raise InputError(f"{missing}: no timestamps, while the other files have them; give --times for KITTI files")
    else:
        rig = _associate(files, trajs, offsets, max_dt, sync)

    valid = rig.valid.all(1)
    if valid.sum() < MIN_FRAMES:
        counts = ", ".join(f"{f}: {len(t)}" for f, t in zip(files, trajs))
        paired = "" if rig.times is None else f"{len(valid)} paired in time, "
        raise InputError(
            f"too few frames: {paired}{int(valid.sum())} with every pose valid ({counts} poses); "
            f"at least {MIN_FRAMES} are needed"
        )
    return rig


def offset_specs(time_offset, cameras: int) -> list[float | str | None]:
    """--time-offset values -> one per camera 1..K: a float, "auto" or None."""
    if time_offset is None:
        return [None] * cameras
    try:
        values = [v if v == "auto" else float(v) for v in time_offset]
    except ValueError:
        values = [math.nan]
    if not all(v == "auto" or math.isfinite(v) for v in values):
        raise InputError(f"--time-offset: expected seconds or 'auto', got {' '.join(map(str, time_offset))}")
    if len(values) == 1:
        return values * cameras
    if len(values) != cameras:
        raise InputError(
            f"--time-offset: {len(values)} values for {cameras} camera{'s' * (cameras != 1)} besides the reference "
            "(camera 0, whose clock the others are put on); give one, or one per camera after it"
        )
    return values


def _associate(files, trajs, offsets, max_dt, sync) -> RigPoses:
    """Bring every camera's poses to camera 0's timestamps; keep the frames every camera has."""
    t0 = trajs[0].times
    period = lambda t: float(np.median(np.diff(t))) if len(t) > 1 else 0.0  # noqa: E731
    resolved, quality, pairs, tolerances, unpaired = [0.0], [None], [], [], []
    for f, t, spec in zip(files[1:], trajs[1:], offsets):
        q = None
        if spec == "auto":
            spec, q = find_time_offset(t0, trajs[0].poses, t.times, t.poses, names=(files[0], f))
        resolved.append(float(spec or 0.0))
        quality.append(q)
        names = (files[0], f)
        if sync == "nearest":
            tolerances.append(0.5 * period(t0) if max_dt is None else max_dt)
            i0, i1 = associate(t0, t.times, tolerances[-1], resolved[-1], names=names)
            pairs.append((i0, t.poses[i1], i1))
        else:
            tolerances.append(INTERPOLATION_MAX_DT_PERIODS * period(t.times) if max_dt is None else max_dt)
            pairs.append(interpolate(t0, t.times, t.poses, tolerances[-1], resolved[-1], names=names))
        span = (t0 >= t.times[0] + resolved[-1]) & (t0 <= t.times[-1] + resolved[-1])
        unpaired.append(int(span.sum()) - int(np.isin(np.flatnonzero(span), pairs[-1][0]).sum()))
    frames = reduce(np.intersect1d, [i0 for i0, _, _ in pairs])
    if not len(frames):
        raise InputError(
            f"no frame of {files[0]} where every camera has a pose ({sync}, max_dt "
            + ", ".join(f"{d:.6g} s" for d in tolerances)
            + "): "
            + ", ".join(f"{f}: {len(i0)} frames" for f, (i0, _, _) in zip(files[1:], pairs))
        )
    at = [np.searchsorted(i0, frames) for i0, _, _ in pairs]
    return RigPoses(
        files,
        np.stack([trajs[0].poses[frames]] + [p[j] for (_, p, _), j in zip(pairs, at)], 1),
        t0[frames],
        np.stack([trajs[0].lines[frames]] + [t.lines[i1[j]] for t, (_, _, i1), j in zip(trajs[1:], pairs, at)], 1),
        resolved,
        quality,
        max(tolerances),
        unpaired,
    )


def calibrate_rig(
    rig: RigPoses,
    head: HeadOptions = HeadOptions(),
    progress: bool | None = False,
    change_test: ChangeTest | None = ChangeTest(),
) -> CalibrationRun:
    """Calibrate cameras 1..K of ``rig`` against camera 0 with the head's options ``head``.

    motion: the head's motion pairing, or ``absolute``: every pose on its own, for poses with independent errors
    (:class:`~ocalib.calib.drivers.absolute.AbsoluteCalibrator`; ``refine`` does not apply; ``pose_error``, only with
    it: ``camera`` (default) or ``world``, where the poses' translation error lives).
    solver: ``exact`` or ``rls``: the on-line head's estimate at every frame (``exact`` through the
    whole-sequence path of :mod:`ocalib.calib.drivers.sequence`, which equals streaming the frames; ``rls`` streams
    them); ``batch`` solves all frames with every pose valid at once (one estimate). refine: the head's (see
    :class:`OnlineCalibrator`; the batch solver refines only with True, and only where rotation is
    observable). progress: a tqdm bar (None: only on a terminal). change_test: the on-line head's test for a change
    of each camera's extrinsic (:class:`~ocalib.calib.drivers.change.ChangeTest`; None: none, the stream taken as one
    rig, e.g. to time the test).
    """
    head = head.checked()
    poses = torch.from_numpy(rig.poses)
    if head.motion == "absolute":
        head = replace(head, pose_error=head.pose_error or "camera")
        calibrator = AbsoluteCalibrator(rig.poses.shape[1], pose_error=head.pose_error, forgetting=head.forgetting,
                                        pose_tolerance=POSE_TOLERANCE)  # fmt: skip
        (final, trace), frames = _stream(calibrator, poses, progress), np.arange(len(poses))
    elif head.solver == "batch":
        final = _batch(poses, rig.valid.all(1), head.motion, head.refine is True)
        trace, frames = trace_rows(final), np.array([len(poses) - 1])
    else:
        final, trace = _online(poses, head, progress)
        trace = {k: v.double().numpy() for k, v in trace.items()}
        final, trace, changes = _follow_changes(rig, head, final, trace, change_test)
        frames = np.arange(len(poses))
    times = rig.times[frames] if rig.times is not None else np.full(len(frames), np.nan)
    trace = {"frame": frames, "time": times} | {k: np.asarray(v, dtype=float) for k, v in trace.items()}
    settings = head.settings() | {"frames": len(poses), "max_dt": rig.max_dt, "pose_error": head.pose_error}
    run = CalibrationRun(rig, final, trace, settings, [])
    tested = head.motion != "absolute" and head.solver != "batch" and change_test is not None
    run.changes = changes if tested else []
    run.warnings = run_warnings(run) + (untested_warnings(run, change_test) if tested else [])
    return run


def calibrate_files(
    files: list[str | Path], head: HeadOptions = HeadOptions(), progress: bool | None = False, **load
) -> CalibrationRun:
    """:func:`load_rig` (``load``: its keyword arguments) then :func:`calibrate_rig`."""
    rig = load_rig(files, **load)
    run = calibrate_rig(rig, head, progress)
    sync = load.get("sync", "interpolate") if rig.times is not None else None
    run.settings.update(format=load.get("format", "auto"), sync=sync)
    return run


def _online(poses: torch.Tensor, head: HeadOptions, progress: bool | None) -> tuple[Calibration, dict]:
    """The on-line head (``exact`` or ``rls``) over every frame (T, C, 4, 4) -> (the last estimate, the trace)."""
    if head.solver == "exact":
        return _sequence(poses, head, progress)
    calibrator = OnlineCalibrator(poses.shape[1], **head.head_kwargs(), gates=Gates(pose_tolerance=POSE_TOLERANCE))
    return _stream(calibrator, poses, progress)


def _follow_changes(
    rig: RigPoses, head: HeadOptions, final: Calibration, trace: dict[str, np.ndarray], test: ChangeTest | None
) -> tuple[Calibration, dict[str, np.ndarray], list[dict]]:
    """Each camera's extrinsic tested for changes over the stream (:func:`~ocalib.calib.drivers.change.first_change`);
    where one is found, camera k's head restarts at its first frame (on camera 0 and camera k alone) and its estimates
    replace the old from the frame it was detected. Returns the final estimate, the trace (camera k's columns
    spliced; ``change_frame`` (F, K): at the frame a change was detected, its first frame, else NaN) and the changes:
    camera file, first frame, frame detected, the step from the estimate before to the one that followed (degrees,
    camera-0 units). ``test`` None: none tested (``change_frame`` all NaN)."""
    changes, trace["change_frame"] = [], np.full(trace["scale"].shape[:2], np.nan)
    if test is None:
        return final, trace, changes
    poses = np.where(rig.valid[..., None, None], rig.poses, np.nan)
    for k in range(1, poses.shape[1]):
        start, found = 0, []
        while change := first_change(poses[start:, 0], poses[start:, k], *_estimates(trace, k, start),
                                     test, trace["rotation_std_deg"][start:, k - 1]):  # fmt: skip
            onset, detected = start + change.frame, start + change.detected
            new_final, new_trace = _online(torch.from_numpy(rig.poses[onset:, [0, k]]), head, progress=False)
            for name, values in new_trace.items():
                trace[name][detected:, k - 1] = values[detected - onset :, 0].double().numpy()
            final = final.with_camera(k - 1, new_final)
            found.append((onset, detected, _estimates(trace, k, onset - 1, onset)))
            trace["change_frame"][detected, k - 1] = onset
            start = onset
        ends = [detected for _, detected, _ in found[1:]] + [len(poses)]
        for (onset, detected, (R0, t0, _)), end in zip(found, ends):
            R1, t1, _ = _estimates(trace, k, end - 1, end)
            rotation, translation = step_size(R0[0], t0[0], R1[0], t1[0])
            changes.append({"camera": rig.files[k], "frame": onset, "detected": detected,
                            "time": None if rig.times is None else float(rig.times[onset]),
                            "rotation_change_deg": rotation, "translation_change": translation})  # fmt: skip
    return final, trace, changes


def _estimates(trace: dict[str, np.ndarray], k: int, start: int, stop: int | None = None):
    """Camera k's estimates over frames [start, stop) of ``trace``: rotations (n, 3, 3), translations (n, 3), scales
    (n,)."""
    rows = slice(start, stop)
    R = quaternion_to_rotation_matrix(torch.from_numpy(trace["quaternion"][rows, k - 1])).numpy()
    return R, trace["translation"][rows, k - 1], trace["scale"][rows, k - 1, 0]


@contextlib.contextmanager
def _single_thread():
    """One intra-op thread: the tensors are small, and threads only add hand-over cost (measured: the
    whole-sequence path on 20,000 frames took 0.65 s with one thread, 19 s with two on a loaded machine)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


def _sequence(poses: torch.Tensor, head: HeadOptions, progress: bool | None) -> tuple[Calibration, dict]:
    """Every frame (T, C, 4, 4) at once (:func:`~ocalib.calib.drivers.sequence.calibrate_sequence`) -> (the last
    estimate, the trace of every frame); the uncertainty is computed ``TRACE_CHUNK`` frames at a time."""
    with (
        torch.inference_mode(),
        _single_thread(),
        tqdm(total=len(poses), unit="frame", disable=None if progress is None else not progress, leave=False) as bar,
    ):
        out = calibrate_sequence(poses, motion=head.motion, forgetting=head.forgetting, refine=head.refine,
                                 gates=Gates(pose_tolerance=POSE_TOLERANCE), progress=bar.update)  # fmt: skip
        names = [f.name for f in fields(Calibration)]
        part = lambda a, b: Calibration(**{n: getattr(out, n)[a:b] for n in names})  # noqa: E731
        chunks = [trace_rows(part(a, a + TRACE_CHUNK)) for a in range(0, len(poses), TRACE_CHUNK)]
        last = part(len(poses) - 1, len(poses))
        bar.set_postfix_str(progress_text(last), refresh=False)
    return last, {k: torch.cat([c[k] for c in chunks]) for k in chunks[0]}


def _stream(
    head: OnlineCalibrator | AbsoluteCalibrator, poses: torch.Tensor, progress: bool | None
) -> tuple[Calibration, dict]:
    """Every frame (T, C, 4, 4) through the head -> (the last estimate, the trace of every frame).

    The head's outputs are gathered ``PROGRESS_EVERY`` frames at a time into one Calibration with the
    frames on its batch axis, whose uncertainty is then computed at once (it is lazy in the head).
    """
    chunks, pending = [], []
    with (
        torch.inference_mode(),
        _single_thread(),
        tqdm(total=len(poses), unit="frame", disable=None if progress is None else not progress, leave=False) as bar,
    ):
        for t, pose in enumerate(poses):
            pending.append(head(pose))
            if len(pending) == PROGRESS_EVERY or t == len(poses) - 1:
                chunks.append(trace_rows(stack_estimates(pending)))
                bar.update(len(pending))
                last, pending = pending[-1], []
                bar.set_postfix_str(progress_text(last), refresh=False)
    return last, {k: torch.cat([c[k] for c in chunks]) for k in chunks[0]}


def _batch(poses: torch.Tensor, valid: np.ndarray, motion: str, refine: bool) -> Calibration:
    """The batch solution of the frames with every pose valid, as a one-frame Calibration (1, K).

    Its uncertainty comes from the same batch system (rotation blocks and translation features).
    """
    out = batch_calibrate(poses[torch.from_numpy(valid)], motion, refine=refine)
    _, S, V = batch_rotation(out["blocks"])
    features = out["features"]
    rows = torch.full(S.shape[:1], float(out["blocks"].shape[1]), dtype=S.dtype)  # motion pairs
    planar = planar_motion(S, rows)
    used = torch.full(S.shape[:1], int(valid.sum()))
    return Calibration(
        rotation=out["rotation"][None],
        quaternion=out["quaternion"][None],
        translation=out["translation"][None],
        scale=out["scale"][None],
        rotation_singular_values=S[None],
        rotation_observable=rotation_observable(S, rows)[None],
        planar_motion=planar[None],
        planar_axis=torch.where(planar[:, None], planar_axis(V), 0.0)[None],
        frames_used=used[None],
        frames_rejected=(len(valid) - used)[None],
        rotation_basis=V[None],
        rotation_rows=rows[None],
        translation_moment=row_statistics(features).sum(-2)[None],
        translation_rows=rows[None],
        refined=out["refined"][None],
        translation_moment_reverse=row_statistics(features[:, 1::2]).sum(-2)[None],  # rows: (pair, direction)
    )
