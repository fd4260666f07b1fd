"""Rig calibration from pose files: the engine of ``ocalib calibrate-poses``.

:func:`load_rig` reads one pose file per camera (KITTI or TUM), puts the cameras on camera 0's clock
and pairs their poses into synchronised frames; :func:`calibrate_rig` streams the frames through the
on-line head (:class:`~ocalib.calib.online.OnlineCalibrator`), or solves them at once (``batch``), and
returns a :class:`CalibrationRun` with the per-frame estimates, the result JSON and warnings.

Convention: poses camera-to-world (each camera in its own world and units: only motions are used);
the result is ``T_cam0_camk`` (``p_cam0 = R p_camk + t``, camera-0 units) and the scale that multiplies
camera-k units into camera-0 units; a time offset is ADDED to camera k's timestamps (``t0 = tk + offset``).
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass, field, fields, replace
from functools import reduce
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from ocalib.calib.absolute import POSE_ERRORS, ROTATION_GAP_MIN, AbsoluteCalibrator
from ocalib.calib.batch import batch_calibrate
from ocalib.calib.online import OnlineCalibrator
from ocalib.calib.planar import planar_axis
from ocalib.calib.result import Calibration
from ocalib.calib.rotation import (
    ROTATION_OBSERVABLE_MIN_SV,
    ROTATION_OBSERVABLE_SIGNIFICANCE,
    batch_rotation,
    planar_motion,
    rotation_observable,
)
from ocalib.calib.sequence import calibrate_sequence
from ocalib.errors import InputError
from ocalib.io.poses import describe_invalid, pose_validity, read_poses
from ocalib.io.timing import (
    INTERPOLATION_MAX_DT_PERIODS,
    associate,
    estimate_time_offset,
    interpolate,
    refine_time_offset,
)

MIN_FRAMES = 3  # synchronised frames with every pose valid, below which there is nothing to calibrate
PROGRESS_EVERY = 100  # frames between progress-bar updates (and between copies of the per-frame estimates)
TRACE_CHUNK = 4096  # frames whose uncertainty is computed at once
POSE_TOLERANCE = 1e-3  # rotation orthonormality error above which a pose is invalid (as the head's default)
SOLVERS = ("exact", "rls", "batch")
# A translation residual above this share of camera 0's motion (RMS) is reported. Measured on the held-out rigs
# (docs/calibnet.md): true poses with VO-like drift 0.002-0.005 leave 1-12 %, OpenCV VO 11-60 %, the aligned pose
# network 26-49 % (81-98 % before alignment); the translations of the last two are 0.4-25 baselines off.
TRANSLATION_RESIDUAL_WARNING = 0.15
UNPAIRED_WARNING = 0.1  # camera-0 stamps left without a camera-k pose inside its span, as a share of the frames kept
SYNC_MODES = ("interpolate", "nearest")  # how timestamped cameras meet camera 0's stamps (see load_rig)

# The per-camera keys of the result JSON, in their documented order (README).
CAMERA_KEYS = (
    "camera", "rotation", "quaternion_wxyz", "translation", "scale", "time_offset", "frames_used",
    "frames_rejected", "rotation_std_deg", "translation_std", "scale_std", "observability",
)  # fmt: skip


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

    @property
    def valid(self) -> np.ndarray:
        """(T, C) bool: finite pose with an orthonormal rotation."""
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
    offsets = _offset_specs(time_offset, len(files) - 1)
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


def _offset_specs(time_offset, cameras: int) -> list[float | str | None]:
    """--time-offset values -> one per camera 1..K: a float, "auto" or None."""
    if time_offset is None:
        return [None] * cameras
    try:
        values = [v if v == "auto" else float(v) for v in time_offset]
    except ValueError:
        raise InputError(f"--time-offset: expected seconds or 'auto', got {' '.join(map(str, time_offset))}") from None
    if len(values) == 1:
        return values * cameras
    if len(values) != cameras:
        raise InputError(f"--time-offset: {len(values)} values for {cameras} cameras; give one, or one per camera")
    return values


def _associate(files, trajs, offsets, max_dt, sync) -> RigPoses:
    """Bring every camera's poses to camera 0's timestamps; keep the frames every camera has."""
    t0 = trajs[0].times
    period = lambda t: float(np.median(np.diff(t))) if len(t) > 1 else 0.0  # noqa: E731
    resolved, quality, pairs, tolerances, unpaired = [0.0], [None], [], [], []
    for f, t, spec in zip(files[1:], trajs[1:], offsets):
        q = None
        if spec == "auto":  # the angular speeds' correlation, then the rig's rotation constraint within 2 frames
            coarse, q = estimate_time_offset(t0, trajs[0].poses, t.times, t.poses, names=(files[0], f))
            radius = 2 * max(period(t0), period(t.times))
            spec = refine_time_offset(t0, trajs[0].poses, t.times, t.poses, coarse, radius)
            q = replace(q, angular_speed_offset=coarse)
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


@dataclass
class CalibrationRun:
    """The outcome of :func:`calibrate_rig`.

    final: the estimate after the last frame, fields (1, K). trace: per-frame estimates, name -> array
    (F, K, n) for F estimates (every frame; the last only for the batch solver), with ``frame`` and
    ``time`` (F,) (time NaN without timestamps); angles in degrees.
    """

    rig: RigPoses
    final: Calibration
    trace: dict[str, np.ndarray]
    settings: dict
    warnings: list[str]

    def result_json(self) -> dict:
        """The result JSON (README), plus ``settings``, ``time_offset_estimates`` and ``warnings``."""
        extrinsics = []
        for k, f in enumerate(self.rig.files[1:]):
            cam = self.final.camera_json(0, k)
            cam.update(camera=f, time_offset=self.rig.time_offsets[k + 1])
            extrinsics.append({key: cam.pop(key) for key in CAMERA_KEYS} | cam)
        out = {"reference": self.rig.files[0], "extrinsics": extrinsics, "settings": self.settings}
        estimated = [
            {
                "camera": f,
                "time_offset": o,
                "correlation": q.correlation,
                "runner_up": q.runner_up,
                "overlap_s": q.overlap,
                "angular_speed_offset": q.angular_speed_offset,
            }
            for f, o, q in zip(self.rig.files, self.rig.time_offsets, self.rig.offset_quality)
            if q is not None
        ]
        if estimated:
            out["time_offset_estimates"] = estimated
        out["warnings"] = self.warnings
        return out

    def trace_table(self) -> tuple[list[str], np.ndarray]:
        """The trace as a long table, one row per (frame, camera k): header and rows (F * K, n)."""
        tr = self.trace
        F, K = tr["quaternion"].shape[:2]
        names = {
            "quaternion": ["qw", "qx", "qy", "qz"], "translation": ["tx", "ty", "tz"],
            "rotation_singular_values": [f"rotation_sv{i}" for i in range(tr["rotation_singular_values"].shape[-1])],
            "rotation_std_deg": ["rotation_std_x_deg", "rotation_std_y_deg", "rotation_std_z_deg"],
            "translation_std": ["translation_std_x", "translation_std_y", "translation_std_z"],
            "bundle_quaternion": ["ba_qw", "ba_qx", "ba_qy", "ba_qz"], "bundle_translation": ["ba_tx", "ba_ty", "ba_tz"],
        }  # fmt: skip
        header, columns = (
            ["frame", "time", "camera"],
            [
                np.repeat(tr["frame"], K),
                np.repeat(tr["time"], K),
                np.tile(np.arange(1, K + 1), F),
            ],
        )
        for name, values in tr.items():
            if name in ("frame", "time"):
                continue
            header += names.get(name, [name])
            columns += list(values.reshape(F * K, -1).T)
        return header, np.stack(columns, 1)

    def write_trace(self, path: str | Path) -> None:
        """Write :meth:`trace_table` as CSV with a header line."""
        header, rows = self.trace_table()
        np.savetxt(path, rows, fmt="%.10g", delimiter=",", header=",".join(header), comments="")


def calibrate_rig(
    rig: RigPoses,
    motion: str = "multi",
    solver: str = "exact",
    forgetting: float = 1.0,
    refine: bool | str = True,
    progress: bool | None = False,
    pose_error: str | None = None,
) -> CalibrationRun:
    """Calibrate cameras 1..K of ``rig`` against camera 0.

    motion: the head's motion pairing, or ``absolute``: every pose on its own, for poses with independent errors
    (:class:`~ocalib.calib.absolute.AbsoluteCalibrator`; ``refine`` does not apply; ``pose_error``, only with it:
    ``camera`` (default) or ``world``, where the poses' translation error lives).
    solver: ``exact`` or ``rls``: the on-line head's estimate at every frame (``exact`` through the
    whole-sequence path of :mod:`ocalib.calib.sequence`, which equals streaming the frames; ``rls`` streams
    them); ``batch`` solves all frames with every pose valid at once (one estimate). refine: the head's (see
    :class:`OnlineCalibrator`; the batch solver refines only with True, and only where rotation is
    observable). progress: a tqdm bar (None: only on a terminal).
    """
    if solver not in SOLVERS:
        raise InputError(f"unknown solver {solver!r}: {', '.join(SOLVERS)}")
    if not 0 < forgetting <= 1:
        raise InputError(f"forgetting must be in (0, 1], got {forgetting}")
    poses = torch.from_numpy(rig.poses)
    if motion == "absolute" and solver != "exact":
        raise InputError(
            f"motion 'absolute' has its own solver (on-line AX = YB); leave --solver at exact, not {solver!r}"
        )
    if pose_error is not None and motion != "absolute":
        raise InputError(f"--pose-error describes absolute poses; it needs --motion absolute, not {motion!r}")
    if motion == "absolute":
        pose_error = pose_error or "camera"
        if pose_error not in POSE_ERRORS:
            raise InputError(f"unknown pose error {pose_error!r}: {', '.join(POSE_ERRORS)}")
        head = AbsoluteCalibrator(
            rig.poses.shape[1], pose_error=pose_error, forgetting=forgetting, pose_tolerance=POSE_TOLERANCE
        )
        (final, trace), frames = _stream(head, poses, progress), np.arange(len(poses))
    elif solver == "batch":
        final = _batch(poses, rig.valid.all(1), motion, refine is True)
        trace, frames = trace_rows(final), np.array([len(poses) - 1])
    elif solver == "exact":
        (final, trace), frames = _sequence(poses, motion, forgetting, refine, progress), np.arange(len(poses))
    else:
        head = OnlineCalibrator(rig.poses.shape[1], motion=motion, solver=solver, forgetting=forgetting,
                                refine=refine, pose_tolerance=POSE_TOLERANCE)  # fmt: skip
        (final, trace), frames = _stream(head, poses, progress), np.arange(len(poses))
    times = rig.times[frames] if rig.times is not None else np.full(len(frames), np.nan)
    trace = {"frame": frames, "time": times} | {k: v.double().numpy() for k, v in trace.items()}
    settings = {
        "motion": motion,
        "solver": solver,
        "forgetting": forgetting,
        "refine": refine,
        "frames": len(poses),
        "max_dt": rig.max_dt,
        "pose_error": pose_error,
    }
    run = CalibrationRun(rig, final, trace, settings, [])
    run.warnings = run_warnings(run)
    return run


def calibrate_files(
    files: list[str | Path],
    format: str = "auto",
    times: list[str | Path] | None = None,
    time_offset: list[float | str] | None = None,
    max_dt: float | None = None,
    motion: str = "multi",
    solver: str = "exact",
    forgetting: float = 1.0,
    refine: bool | str = True,
    progress: bool | None = False,
    sync: str = "interpolate",
    pose_error: str | None = None,
) -> CalibrationRun:
    """:func:`load_rig` then :func:`calibrate_rig`; see both for the arguments."""
    rig = load_rig(files, format, times, time_offset, max_dt, sync)
    run = calibrate_rig(rig, motion, solver, forgetting, refine, progress, pose_error)
    run.settings.update(format=format, sync=sync if rig.times is not None else None)
    return run


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


def _sequence(
    poses: torch.Tensor, motion: str, forgetting: float, refine: bool | str, progress: bool | None
) -> tuple[Calibration, dict]:
    """Every frame (T, C, 4, 4) at once (:func:`~ocalib.calib.sequence.calibrate_sequence`) -> (the last
    estimate, the trace of every frame); the uncertainty is computed ``TRACE_CHUNK`` frames at a time."""
    with (
        torch.inference_mode(),
        _single_thread(),
        tqdm(total=len(poses), unit="frame", disable=None if progress is None else not progress, leave=False) as bar,
    ):
        out = calibrate_sequence(poses, motion=motion, forgetting=forgetting, refine=refine,
                                 pose_tolerance=POSE_TOLERANCE, progress=bar.update)  # fmt: skip
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


def stack_estimates(estimates: list[Calibration]) -> Calibration:
    """Per-frame estimates (each (B, K, ...)) -> one Calibration with the frames concatenated on the batch axis."""
    kind = type(estimates[0])  # Calibration or AbsoluteCalibration
    names = [f.name for f in fields(kind)]
    return kind(
        **{
            n: None if getattr(estimates[0], n) is None else torch.cat([getattr(e, n) for e in estimates])
            for n in names
        }
    )


def trace_rows(e: Calibration) -> dict[str, torch.Tensor]:
    """The trace columns of estimates ``e`` (frames on the batch axis): name -> (F, K, n), degrees."""
    return {
        "quaternion": e.quaternion,
        "translation": e.translation,
        "scale": e.scale[..., None],
        "rotation_singular_values": e.rotation_singular_values,
        "rotation_observable": e.rotation_observable[..., None],
        "planar_motion": e.planar_motion[..., None],
        "unobservable_translation_dims": e.translation_unobservable.sum(-1, keepdim=True),
        "rotation_std_deg": torch.rad2deg(e.rotation_std),
        "translation_std": e.translation_std,
        "scale_std": e.scale_std[..., None],
        "rotation_residual_deg": e.residuals["rotation_deg"][..., None],
        "translation_residual": e.residuals["translation_relative"][..., None],
        "frames_used": e.frames_used[..., None],
        "frames_rejected": e.frames_rejected[..., None],
    }


def progress_text(out: Calibration) -> str:
    """Camera 1's current estimate: rotation angle (deg), translation and scale."""
    q, t, s = out.quaternion[0, 0].tolist(), out.translation[0, 0].tolist(), float(out.scale[0, 0])
    angle = math.degrees(2 * math.atan2(math.hypot(*q[1:]), abs(q[0])))
    return f"cam1 rot {angle:.2f}deg t=({t[0]:+.3f},{t[1]:+.3f},{t[2]:+.3f}) s={s:.3f}"


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
        translation_moment=(features.mT @ features)[None],
        translation_rows=rows[None],
        refined=out["refined"][None],
    )


def run_warnings(run: CalibrationRun) -> list[str]:
    """Readable warnings about the input and the final estimate."""
    rig, e = run.rig, run.final
    out = [
        msg
        for c, f in enumerate(rig.files)
        if (msg := describe_invalid(f, pose_validity(rig.poses[:, c], POSE_TOLERANCE), rig.lines[:, c]))
    ]
    frames = len(rig.poses)
    for f, missing in zip(rig.files[1:], rig.unpaired):
        if missing > UNPAIRED_WARNING * frames:
            out.append(
                f"{f}: {missing} of {rig.files[0]}'s stamps inside {f}'s time span found no pose of it (gaps in it "
                f"beyond max_dt = {rig.max_dt:.6g} s); those frames are left out. Check the time offset "
                "(--time-offset auto) or raise --max-dt"
            )
    for k, f in enumerate(rig.files[1:]):
        S = e.rotation_singular_values[0, k].tolist()
        if not bool(e.rotation_observable[0, k]) and run.settings["motion"] == "absolute":
            out.append(
                f"{f}: rotation not observable: the top two singular values of the rotation sum {_fmt(S[:3])} are less "
                f"than {ROTATION_GAP_MIN:g} per frame apart: the poses rotate about one axis or not at all; absolute "
                "poses cannot calibrate that (no estimate). The motion pairs (--motion multi) recover a planar rotation"
            )
        elif not bool(e.rotation_observable[0, k]) and not bool(e.planar_motion[0, k]):
            out.append(
                f"{f}: rotation not observable: rotation singular values {_fmt(S)}, the third must exceed "
                f"{ROTATION_OBSERVABLE_MIN_SV} and stand out of the fourth (the noise floor; significance "
                f"{ROTATION_OBSERVABLE_SIGNIFICANCE:g}, see ocalib.calib.rotation). The motion rotates too "
                "little or about too few axes (pure translation?); rotation, translation and scale are unreliable"
            )
        if bool(e.planar_motion[0, k]):
            axis = e.planar_axis[0, k].tolist()
            out.append(
                f"{f}: planar motion: every rotation is about one axis {_fmt(axis)} (camera 0's frame); the rotation "
                "is recovered through the translation constraint and the translation along that axis is unobservable "
                "(its std null; the value there is not a measurement)"
            )
        unobservable = e.translation_directions[0, k].mT[e.translation_unobservable[0, k]].tolist()
        if unobservable and not bool(e.planar_motion[0, k]):
            out.append(
                f"{f}: translation unobservable along {', '.join(_fmt(d) for d in unobservable)} (camera 0's frame)"
            )
        residual = float(e.residuals["translation_relative"][0, k])
        if residual > TRANSLATION_RESIDUAL_WARNING:
            out.append(
                f"{f}: the translation equations leave {100 * residual:.0f} % of camera 0's motion unexplained (RMS): "
                "the translations of the two cameras do not agree with any rigid rig (a front end whose scale drifts "
                "or whose translation directions are off?); translation and scale are not supported by the data"
            )
        scale = float(e.scale[0, k])
        if not scale > 0:
            out.append(
                f"{f}: scale {scale:.4g} is not positive: this camera's translations point against what camera 0's "
                "imply (a front end with an inconsistent scale or a flipped translation sign?); translation and "
                "scale are not meaningful"
            )
        rejected = int(e.frames_rejected[0, k])
        if rejected:
            out.append(
                f"{f}: {rejected} of {frames} frames rejected (an invalid pose of camera 0 or this camera, "
                "or motions failing the screw-congruence gate)"
            )
    if run.settings["motion"] == "first":
        out.append(
            "frame-0 pairing: every motion shares frame 0's pose error, which no residual shows; the standard "
            "deviations are several times too small (6-11x in simulation: docs/simulation.md, bench/bench_uncertainty.py)"
        )
    if run.settings["solver"] == "batch" and bool(e.planar_motion.any()):
        out.append("the batch solver does not recover rotation under planar motion; use --solver exact")
    return out


def _fmt(values) -> str:
    return "[" + ", ".join(f"{v:.4g}" for v in values) + "]"
