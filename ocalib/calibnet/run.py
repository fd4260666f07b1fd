"""Calibrate a rig from its images: the engine of ``ocalib calibrate``.

:func:`calibrate_images` opens a sequence of any supported layout, streams its synchronised frames
through a front end (:mod:`ocalib.frontend`) and the calibration head on one graph
(:class:`~ocalib.calibnet.net.OnlineCalibrationNet`), and returns a
:class:`~ocalib.calib.poses.pipeline.CalibrationRun` (the JSON of ``calibrate-poses``, the per-frame trace,
warnings) with the front end's trajectories, plus errors against the ground truth when the sequence has it.

Convention: the result is ``T_cam0_camk`` (``p_cam0 = R p_camk + t``) in camera 0's front-end units and
the scale that multiplies camera k's front-end units into camera 0's.
"""

from __future__ import annotations

import inspect
import os
import sys
import time
import typing
from dataclasses import dataclass, fields, replace
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader
from tqdm import tqdm

from ocalib.calib.drivers.clock import find_time_offset
from ocalib.calib.drivers.online import OnlineCalibrator
from ocalib.calib.drivers.options import MOTION_CHOICES, HeadOptions
from ocalib.calib.drivers.result import Calibration
from ocalib.calib.poses.pipeline import RigPoses
from ocalib.calib.poses.report import (
    SOURCES,
    CalibrationRun,
    progress_text,
    run_warnings,
    stack_estimates,
    trace_rows,
)
from ocalib.calibnet.net import OnlineCalibrationNet
from ocalib.calibnet.sequence import MIN_FRAMES, open_calibration_sequence
from ocalib.data.sequence import Sequence
from ocalib.data.static import check_motion
from ocalib.data.synchronise import clocks
from ocalib.errors import InputError, deferred_interrupts
from ocalib.eval.calibration_metrics import extrinsic_errors
from ocalib.eval.pose_metrics import congruence_residual
from ocalib.frontend import AUTO, AUTO_FRAMES, FRONTENDS, FrontEndOptions, build_frontend
from ocalib.frontend.base import FrontEnd
from ocalib.frontend.recorded import EgoMotion, RecordedFrontEnd, ReplayedFrontEnd, ego_motion_fingerprint
from ocalib.io.jsonable import finite_or_null

if typing.TYPE_CHECKING:
    from ocalib.rigba.result import RigAdjustment
    from ocalib.rigba.stream import OnlineRigStage

TRACE_EVERY = 50  # frames gathered before their estimates are copied to the trace
SYNC_WARNING = 0.1  # frames: paired frames further apart than this (median) are warned about
DETERMINED_ROTATION_DEG = 0.5  # a reported rotation's 1-sigma over this (deg, any axis): not determined (a target)


@dataclass
class ImageCalibration:
    """:func:`calibrate_images`'s outcome: the run (JSON, trace, warnings), the ground-truth errors, where the
    on-line rig estimator ran (:class:`ocalib.rigba.stream.OnlineRigStage`) its states and errors, and where the rig
    bundle adjustment ran (:func:`ocalib.calibnet.bundle.refine_calibration`) its result and errors."""

    run: CalibrationRun
    errors: list[dict] | None  # per camera k >= 1, see :func:`ocalib.eval.calibration_metrics.extrinsic_errors`
    truth: np.ndarray | None = None  # (K, 4, 4) the true T_cam0_camk of cameras k >= 1 at frame 0, where known
    sequence: Sequence | None = None  # the sequence calibrated (its first settings["frames"] frames)
    bundle: RigAdjustment | None = None  # the rig bundle adjustment's result
    bundle_errors: list[dict] | None = (
        None  # its ground-truth errors, see :func:`ocalib.rigba.evaluate.adjustment_errors`
    )
    rig: OnlineRigStage | None = None  # the on-line rig estimator
    rig_errors: list[dict] | None = None  # its final estimate's errors against the truth at the last frame

    def result_json(self) -> dict:
        """The JSON of ``calibrate-poses``. ``extrinsics`` hold the best final result per camera, its ``source``
        saying whose: the bundle adjustment's where it is trusted, the camera did not move mid-run and its frames
        pair with camera 0's within ``SYNC_WARNING`` of a frame, else the on-line rig estimator's (which places each
        image at the rig's pose when it was captured) where it determined the camera's rotation (a translation it
        leaves loose is flagged, not replaced by the head's, whose translation rests on monocular scale), else the
        head's; ``online_extrinsics`` the head's,
        ``rig_estimator`` the on-line estimator's final state and cost, ``changes`` the changes it found,
        ``bundle_adjustment`` the adjustment's figures, ``synchronisation`` how cameras on clocks of their own were
        paired (with the true offset where the layout knows it); ``units`` says what the translations are in."""
        doc = self.run.result_json()
        doc["units"] = "camera 0's front-end units"
        if self.sequence is not None and self.sequence.pairing is not None:
            pairing, cameras = self.sequence.pairing, self.sequence.cameras
            doc["synchronisation"] = [
                {"camera": cameras[k].name} | pairing.camera_json(k) for k in range(1, len(cameras))
            ]
            for entry, cam in zip(doc["synchronisation"], cameras[1:]):
                if cam.time_offset is not None:  # the truth, where the layout knows it (rendered rigs)
                    entry["true_time_offset"] = cam.time_offset - (cameras[0].time_offset or 0.0)
            placed = self.rig is not None and self.rig.final is not None  # the estimator ran and has a result
            doc["warnings"] = doc["warnings"] + list(pairing.warnings) + _pairing_warnings(self.sequence, placed)
        online = doc["extrinsics"]
        errors = self.errors
        if self.bundle is not None or self.rig is not None:
            doc["online_extrinsics"] = online
            if self.errors is not None:
                doc["online_ground_truth_errors"] = finite_or_null(self.errors)
        if self.rig is not None:
            doc["rig_estimator"] = finite_or_null(self.rig.result_json())
            doc["changes"] = self.rig.changes_json()
            doc["warnings"] = doc["warnings"] + self.rig.warnings
            if self.rig_errors is not None:
                doc["rig_estimator_ground_truth_errors"] = finite_or_null(self.rig_errors)
        if self.bundle is not None:
            from ocalib.rigba.result import camera_json

            doc["extrinsics"] = [camera_json(self.bundle, k + 1, e) for k, e in enumerate(online)]
            doc["units"] = self.bundle.units
            doc["bundle_adjustment"] = finite_or_null(self.bundle.stats)
            doc["warnings"] = doc["warnings"] + self.bundle.warnings
            errors = self.bundle_errors
        rig = doc.get("rig_estimator", {}).get("extrinsics", [])
        moved = {c["camera"] for c in doc.get("changes", [])}
        apart = {self.sequence.names[k] for k in _apart(self.sequence)} if self.sequence is not None else set()
        undetermined = {} if self.rig is None else self.rig.undetermined()
        for k, estimate in enumerate(rig):
            if doc["extrinsics"][k].get("source") != "bundle_adjustment" or estimate["camera"] in moved | apart:
                if k + 1 in undetermined:
                    whose = SOURCES.get(doc["extrinsics"][k].get("source"), "the on-line head")
                    doc["warnings"].append(
                        f"on-line rig estimator: {estimate['camera']}: not reported, {undetermined[k + 1]}; the "
                        f"extrinsic is {whose}'s"
                    )
                    continue
                keys = ("rotation", "quaternion_wxyz", "translation", "rotation_std_deg", "translation_std", "source")
                doc["extrinsics"][k] = online[k] | {key: estimate[key] for key in keys}
                doc["units"] = "metres"
                if errors is not None and self.rig_errors is not None:
                    errors = [*errors[:k], self.rig_errors[k], *errors[k + 1 :]]
        if errors is not None:
            doc["ground_truth_errors"] = finite_or_null(errors)
        doc["warnings"] = _replaced_said(doc["warnings"], doc["extrinsics"])
        for entry in doc["extrinsics"]:
            reason = not_determined(entry)
            entry["determined"] = reason is None
            if reason is not None:
                whose = SOURCES.get(entry.get("source"), "the on-line head")
                doc["warnings"].append(
                    f"{entry['camera']}: the extrinsic reported ({whose}'s) is not determined: {reason}"
                )
        return doc


def not_determined(entry: dict) -> str | None:
    """Why the reported extrinsic ``entry`` (an object of the JSON's ``extrinsics``) is not determined to the
    targets' precision: no stated 1-sigma, a rotation 1-sigma over ``DETERMINED_ROTATION_DEG`` about an axis, or
    fewer than two translation axes with a 1-sigma within ``WEAK_SHARE`` of the lever arm (a car's height is never
    pinned; None: unobservable); None where it is determined."""
    from ocalib.rigba.covariance import WEAK_SHARE

    rotation, translation = entry.get("rotation_std_deg"), entry.get("translation_std")
    if rotation is None or translation is None or None in rotation:
        return "no 1-sigma stated"
    if max(rotation) > DETERMINED_ROTATION_DEG:
        return f"its rotation's 1-sigma is {max(rotation):.2f} deg (over {DETERMINED_ROTATION_DEG:g})"
    lever_arm = float(np.linalg.norm(entry["translation"]))
    pinned = [s for s in translation if s is not None and s <= WEAK_SHARE * lever_arm]
    if len(pinned) < 2:
        return f"fewer than two translation axes have a 1-sigma within {WEAK_SHARE:.0%} of the lever arm"
    return None


def _apart(sequence: Sequence) -> dict[int, float]:
    """The cameras whose frames pair with camera 0's more than ``SYNC_WARNING`` of a frame apart -> their median gap
    (seconds)."""
    if sequence.pairing is None:
        return {}
    period = float(np.median(np.diff(sequence.times)))
    gaps = np.median(np.abs(sequence.pairing.residuals), axis=0)
    return {k: float(gaps[k]) for k in range(1, len(gaps)) if gaps[k] > SYNC_WARNING * period}


def _pairing_warnings(sequence: Sequence, placed: bool = False) -> list[str]:
    """A warning per camera of :func:`_apart`: the head and the bundle adjustment take a frame's rig pose as camera
    0's, so the camera is seen where the rig was that much earlier or later; ``placed``: the on-line rig estimator
    ran, which places each image at the rig's pose when it was captured."""
    period = float(np.median(np.diff(sequence.times)))
    out = []
    for k, gap in _apart(sequence).items():
        cause = (
            "the head's and the bundle adjustment's translations are biased by the rig's motion in that time; the "
            "on-line rig estimator's, which places each image at the rig's pose when it was captured, is the result"
            if placed
            else "its translation is biased by the rig's motion in that time, badly so where the lever arm is short "
            "against the rig's speed; give --metric-trajectory (the on-line rig estimator places each image at its "
            "own capture time), trigger the cameras together, or record at a higher frame rate"
        )
        out.append(
            f"{sequence.names[k]}: its frames pair with {sequence.names[0]}'s {gap:.3f} s ({gap / period:.2f} "
            f"frames) apart: {cause}"
        )
    return out


def _replaced_said(warnings: list[str], extrinsics: list[dict]) -> list[str]:
    """The head's warnings that its translation is not supported, said as the head's where a later stage's result
    replaced it."""
    out = []
    for w in warnings:
        e = next((e for e in extrinsics if w.startswith(f"{e['camera']}: the translation equations")), None)
        if e is not None and e.get("source") in SOURCES:
            w = f"on-line head: {w}; its translation is replaced by {SOURCES[e['source']]}'s"
        out.append(w)
    return out


def _trajectories(front_end: FrontEnd, sequence: Sequence, device: str, frames: int, desc: str) -> np.ndarray:
    """Every camera's trajectory (frames, C, 4, 4) from ``front_end`` over the first ``frames``."""
    net = OnlineCalibrationNet(front_end, OnlineCalibrator(len(sequence.cameras))).to(device)
    net.head.load_kernel()
    return _stream(net, front_end.frames(sequence), frames, None, None, desc)[2]


def choose_frontend(sequence: Sequence, frontend: FrontEndOptions, device: str, frames: int):
    """The registered front end whose motions over the first ``frames`` frames best keep the rig's screw congruence
    (:func:`~ocalib.eval.pose_metrics.congruence_residual`: no truth needed) -> (its options, resolved; the
    residual of every front end tried; the chosen front end with its motions over those frames recorded, to be
    streamed on from there, or None where its motions depend on the head's estimate and so are to be computed
    again). ``frontend``: :data:`~ocalib.frontend.AUTO` with the network's settings."""
    tried, ran = {}, {}
    for name in FRONTENDS:
        options = (replace(frontend, name=name) if name == "network" else FrontEndOptions(name)).resolved()
        ran[name] = RecordedFrontEnd(build_frontend(sequence, options, device))
        desc = f"trying the {name} front end"
        tried[name] = congruence_residual(_trajectories(ran[name], sequence, device, frames, desc))
    best = min(tried, key=lambda name: (np.isnan(tried[name]), tried[name]))
    chosen = replace(frontend, name=best) if best == "network" else FrontEndOptions(best)
    return chosen.resolved(), tried, None if ran[best].uses_rig_rotation else ran[best]


def _front_end(sequence: Sequence, frontend: FrontEndOptions, device: str, frames: int):
    """The front end of ``frontend`` for the run (with :data:`~ocalib.frontend.AUTO`, the one
    :func:`choose_frontend` picks on the first frames) -> (it, the result JSON's front-end entries)."""
    if frontend.name != AUTO:
        return build_frontend(sequence, frontend, device), frontend.settings()
    chosen, tried, front_end = choose_frontend(sequence, frontend, device, min(frames, AUTO_FRAMES))
    choice = {"frontend_choice": {"frames": min(frames, AUTO_FRAMES), "congruence_residual": finite_or_null(tried)}}
    return front_end or build_frontend(sequence, chosen, device), chosen.settings() | choice


def _fingerprint(sequence: Sequence, frames: int, frontend: FrontEndOptions, head: HeadOptions) -> str:
    """The :func:`~ocalib.frontend.recorded.ego_motion_fingerprint` of a run of ``frames`` frames of ``sequence``:
    its cameras' intrinsics, lenses and image files (absolute names, sizes, modification times) among what it holds
    (a folder given as a relative or an absolute path is the same run)."""
    pairing = sequence.pairing
    cameras = [
        {
            "name": c.name,
            "K": c.K.tolist(),
            "size": list(c.size),
            "lens": c.distortion and c.distortion.as_dict(),
            "images": [(str(Path(f).resolve()), *_stamp(f)) for f in c.images],
        }
        for c in sequence.cameras
    ]
    run = {
        "code": [inspect.getsource(f) for f in _STREAMING],
        "sequence": str(Path(sequence.path).resolve()),
        "cameras": cameras,
        "frames": frames,
        "frontend": frontend.settings(),
        "head": head.settings(),
        "pairing": None if pairing is None else pairing.frames[:frames].tolist(),
    }
    return ego_motion_fingerprint(run, frontend.checkpoint)


def _stamp(path) -> tuple[int, int]:
    """A file's size and modification time (ns); (-1, -1) where it is not a file (e.g. an image in a bag)."""
    try:
        stat = Path(path).stat()
    except (OSError, TypeError):
        return -1, -1
    return stat.st_size, stat.st_mtime_ns


def _recording(path: str | Path | None, fingerprint: str | None) -> EgoMotion | None:
    """The ego-motion kept at ``path`` where it is this run's (``fingerprint``), else None (a line on stderr says
    why it is not used); an :class:`InputError` where ``path`` is no recording or could not be written."""
    if not path:
        return None
    folder = Path(path).resolve().parent
    if not folder.is_dir():
        raise InputError(f"{path}: its folder does not exist")
    if not os.access(folder, os.W_OK):  # found now, not after the stream
        raise InputError(f"{path}: its folder is not writable")
    if not Path(path).exists():
        return None
    recording = EgoMotion.load(path)
    if recording.fingerprint != fingerprint:
        print(f"{path}: recorded from other frames, settings or code: the front end runs again", file=sys.stderr)
        return None
    return recording


def estimate_offsets(sequence: Sequence, frontend: FrontEndOptions, device: str, frames: int):
    """Each camera k's clock offset from the front end's rotations over the first ``frames`` frames as they are
    -> (offsets, OffsetQuality) per camera k >= 1 (see :func:`ocalib.calib.drivers.clock.find_time_offset`);
    with :data:`~ocalib.frontend.AUTO`, the registry's first front end's."""
    if frontend.name == AUTO:
        frontend = replace(frontend, name=next(iter(FRONTENDS)))
    front_end = build_frontend(sequence, frontend.resolved(), device)
    trajectory = _trajectories(front_end, sequence, device, frames, "finding time offsets")
    stamps = clocks(sequence)
    found = [
        find_time_offset(stamps[0][:frames], trajectory[:, 0], t[:frames], trajectory[:, k], (sequence.names[0], name))
        for k, (t, name) in enumerate(zip(stamps[1:], sequence.names[1:]), 1)
    ]
    return [f for f, _ in found], [q for _, q in found]


def calibrate_images(
    path: str | Path | Sequence,
    cameras: list[str] | None = None,
    frontend: FrontEndOptions = FrontEndOptions(),
    head: HeadOptions = HeadOptions(refine="unobservable"),
    device: str = "cpu",
    max_frames: int | None = None,
    intrinsics: str | None = None,
    progress: bool | None = None,
    on_frame=None,
    time_offset: list[float | str] | None = None,
    ego_motion: str | Path | None = None,
) -> ImageCalibration:
    """Calibrate cameras 1..C-1 of the sequence at ``path`` against camera 0 (the first of ``cameras``).

    path: a sequence folder, or a sequence :func:`open_calibration_sequence` opened (``cameras``, ``intrinsics``
    and ``time_offset`` are then not used). frontend: which front end and its settings
    (:class:`~ocalib.frontend.FrontEndOptions`; :data:`~ocalib.frontend.AUTO`: the one :func:`choose_frontend`
    picks on the first ``AUTO_FRAMES`` frames). head: the head's (``refine`` defaults to ``"unobservable"``: a
    monocular front end's translation directions must not move an observable rotation, see
    :data:`~ocalib.calib.stages.solve.REFINE_MODES`). max_frames: use only the first frames. intrinsics: a file for
    layouts without them. time_offset: for cameras without a shared clock (see :func:`open_calibration_sequence`).
    on_frame(t, estimate): called after every frame (e.g. TensorBoard). progress: a tqdm bar with the current
    estimate (None: on a terminal; elsewhere a line on stderr every ``TRACE_EVERY`` frames). ego_motion: a file
    that keeps the front end's motions: given again where it holds this run's (the same frames, front end, head and
    code: :class:`~ocalib.frontend.recorded.EgoMotion`), else written after the front end has run.
    """
    frontend, head = frontend.resolved(), head.checked(solvers=("exact", "rls"))
    if head.motion not in MOTION_CHOICES:
        raise InputError(f"motion {head.motion!r} is for pose files; from images: {', '.join(MOTION_CHOICES)}")
    if not isinstance(path, Sequence):
        path = open_calibration_sequence(path, cameras, intrinsics, max_frames, time_offset, frontend, device)
    sequence, path = path, path.path
    frames = len(sequence) if max_frames is None else min(len(sequence), max_frames)
    if frames < MIN_FRAMES or len(sequence.cameras) < 2:
        raise InputError(f"{path}: {frames} frames of {len(sequence.cameras)} camera(s): too little to calibrate")
    check_motion(sequence)
    fingerprint = _fingerprint(sequence, frames, frontend, head) if ego_motion else None
    recording = _recording(ego_motion, fingerprint)
    if recording is not None:
        front_end, front_settings = ReplayedFrontEnd(recording), recording.settings
    else:
        front_end, front_settings = _front_end(sequence, frontend, device, frames)
        if ego_motion:
            front_end = RecordedFrontEnd(front_end)  # every motion kept, to be written after the stream
    C = len(sequence.cameras)
    net = OnlineCalibrationNet(front_end, OnlineCalibrator(C, **head.head_kwargs())).to(device)
    net.head.load_kernel()

    final, trace, trajectory = _stream(net, front_end.frames(sequence), frames, progress, on_frame)
    times = sequence.times[:frames] if sequence.times is not None else np.arange(frames, dtype=np.float64)
    trace = {"frame": np.arange(frames), "time": times} | trace
    pairing = sequence.pairing
    if pairing is not None:  # per frame and camera k: what is left of the offset in the pair, t0 - (tk + offset)
        trace["pair_residual_s"] = pairing.residuals[:frames, 1:]
    rig = RigPoses(
        files=sequence.names,
        poses=trajectory,
        times=times,
        lines=np.tile(np.arange(1, frames + 1)[:, None], (1, C)) if pairing is None else pairing.frames[:frames] + 1,
        time_offsets=[None] * C if pairing is None else pairing.offsets.tolist(),
        offset_quality=[None] * C if pairing is None else list(pairing.estimates or [None] * C),
    )
    notes, warnings = front_end.report(sequence.names, frames, final)
    if ego_motion and recording is None:
        motions = np.stack([m.cpu().numpy() for m in front_end.motions])
        EgoMotion(motions, front_settings, (notes, warnings), fingerprint).save(ego_motion)
    settings = front_settings | head.settings() | {"frames": frames, "max_dt": None, "sequence": str(path)}
    run = CalibrationRun(rig, final, trace, settings | notes, [])
    run.warnings = run_warnings(run) + warnings
    errors = None
    extrinsics = [cam.T_cam0_cam for cam in sequence.cameras]
    if all(T is not None for T in extrinsics):
        truth = None
        if all(cam.poses is not None for cam in sequence.cameras):
            truth = np.stack([cam.poses[:frames] for cam in sequence.cameras], 1)
        errors = extrinsic_errors(final, np.stack(extrinsics), trajectory, truth)
    return ImageCalibration(run, errors, None if errors is None else np.stack(extrinsics[1:]), sequence)


def _quiet_worker(worker_id: int) -> None:
    """The loader worker's start: its ``sys.excepthook`` made silent. Its helper thread (multiprocessing's resource
    sharer, which serves the frames' tensors and reports through that hook) breaks when the main process stops
    reading, as Ctrl-C makes it, and the main process says so in one line; an error of the worker's own work reaches
    the main process through the loader, not through the hook."""
    sys.excepthook = lambda *exc_info: None


def _stream(net: OnlineCalibrationNet, dataset, frames: int, progress, on_frame, desc: str = "calibrating"):
    """Run ``net`` on items 0..frames-1 of ``dataset`` -> (last estimate, trace columns, trajectories (T, C, 4, 4));
    ``desc`` names the work on the progress bar."""
    loader = DataLoader(torch.utils.data.Subset(dataset, range(frames)), batch_size=None, num_workers=1,
                        prefetch_factor=4, worker_init_fn=_quiet_worker)  # fmt: skip
    chunks, pending, trajectory = [], [], []
    start = time.perf_counter()
    with (
        torch.inference_mode(),
        tqdm(total=frames, unit="frame", disable=None if progress is None else not progress, desc=desc) as bar,
    ):
        with deferred_interrupts():  # the loader's worker leaves Ctrl-C to this process
            loaded = iter(loader)
        for t, frame in enumerate(loaded):
            out = net(frame)
            pending.append(out)
            trajectory.append(net.trajectory[0].clone())
            if on_frame is not None:
                on_frame(t, out)
            if len(pending) == TRACE_EVERY or t == frames - 1:
                chunks.append({k: v.cpu() for k, v in trace_rows(stack_estimates(pending)).items()})
                bar.update(len(pending))
                last, pending = pending[-1], []
                bar.set_postfix_str(progress_text(last), refresh=False)
                if bar.disable and progress is None:  # not a terminal: a line now and then, for a log
                    rate = (t + 1) / max(time.perf_counter() - start, 1e-9)
                    print(f"{desc}: {t + 1}/{frames} frames ({rate:.1f} frame/s)", file=sys.stderr, flush=True)
    trace = {k: torch.cat([c[k] for c in chunks]).double().numpy() for k in chunks[0]}
    values = {f.name: getattr(last, f.name) for f in fields(Calibration)}
    last = Calibration(**{k: None if v is None else v.cpu() for k, v in values.items()})
    return last, trace, torch.stack(trajectory).cpu().double().numpy()


_STREAMING = (_trajectories, choose_frontend, _front_end, calibrate_images, _stream)  # this module's part in ego-motion
