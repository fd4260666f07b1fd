"""Calibrate a rig from its images: the engine of ``ocalib calibrate``.

:func:`calibrate_sequence` opens a sequence of any supported layout, streams its synchronised frames
through a front end (the pose network, inside :class:`~ocalib.calibnet.net.OnlineCalibrationNet`, or
OpenCV monocular VO per camera) and the calibration head, and returns a
:class:`~ocalib.calib.pipeline.CalibrationRun` (the JSON of ``calibrate-poses``, the per-frame trace,
warnings) with the front end's trajectories, plus errors against the ground truth when the sequence has it.

Convention: the result is ``T_cam0_camk`` (``p_cam0 = R p_camk + t``) in camera 0's front-end units and
the scale that multiplies camera k's front-end units into camera 0's.
"""

from __future__ import annotations

import typing
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader
from tqdm import tqdm

from ocalib.calib.online import OnlineCalibrator
from ocalib.calib.pipeline import CalibrationRun, RigPoses, progress_text, run_warnings, stack_estimates, trace_rows
from ocalib.calib.result import Calibration
from ocalib.calibnet.net import OnlineCalibrationNet
from ocalib.calibnet.truth import extrinsic_errors
from ocalib.data.layout import open_sequence
from ocalib.data.sequence import Sequence
from ocalib.data.stream import RigStream
from ocalib.errors import InputError
from ocalib.eval.predict import FrameImages, check_motion, model_view
from ocalib.io.jsonable import finite_or_null

if typing.TYPE_CHECKING:
    from ocalib.rigba.adjust import RigAdjustment

FRONTENDS = ("network", "opencv")
MIN_FRAMES = 10  # frames below which a sequence is too short to calibrate
# The rotation on planar (car-like) motion, six held-out cars (docs/results-calibrate.md): network front end with
# the rig-held alignment 0.82-2.16 deg, OpenCV VO 0.52-2.49 (five within 2 deg each; OpenCV lower on five).
PLANAR_ADVICE = (
    "planar motion with the network front end: on six held-out cars its rotation was 0.8-2.2 deg off, "
    "OpenCV VO's 0.5-2.5, lower on five of the six; --frontend opencv is worth a try"
)
ALIGNED_WARNING = 0.5  # share of frames with an accepted alignment below which a camera is reported (demo: 99-100 %)
TRACE_EVERY = 50  # frames gathered before their estimates are copied to the trace


@dataclass
class ImageCalibration:
    """:func:`calibrate_sequence`'s outcome: the run (JSON, trace, warnings), the ground-truth errors, and where the
    rig bundle adjustment ran (:func:`ocalib.rigba.stage.refine_calibration`) its result and errors."""

    run: CalibrationRun
    errors: list[dict] | None  # per camera k >= 1, see :func:`ocalib.calibnet.truth.extrinsic_errors`
    truth: np.ndarray | None = None  # (K, 4, 4) the true T_cam0_camk of cameras k >= 1, where the sequence has them
    sequence: Sequence | None = None  # the sequence calibrated (its first settings["frames"] frames)
    bundle: RigAdjustment | None = None  # the rig bundle adjustment's result
    bundle_errors: list[dict] | None = (
        None  # its ground-truth errors, see :func:`ocalib.rigba.adjust.adjustment_errors`
    )

    def result_json(self) -> dict:
        """The JSON of ``calibrate-poses``; with a bundle adjustment, ``extrinsics`` hold its result (the head's where
        it is not trusted) and ``online_extrinsics`` the head's, ``bundle_adjustment`` its figures; ``units`` says what
        the translations are in."""
        doc = self.run.result_json()
        doc["units"] = "camera 0's front-end units"
        if self.bundle is not None:
            from ocalib.rigba.adjust import camera_json

            online = doc["extrinsics"]
            doc["extrinsics"] = [camera_json(self.bundle, k + 1, e) for k, e in enumerate(online)]
            doc["online_extrinsics"] = online
            doc["units"] = self.bundle.units
            doc["bundle_adjustment"] = finite_or_null(self.bundle.stats)
            doc["warnings"] = doc["warnings"] + self.bundle.warnings
        if self.errors is not None:
            key = "online_ground_truth_errors" if self.bundle_errors is not None else "ground_truth_errors"
            doc[key] = finite_or_null(self.errors)
        if self.bundle_errors is not None:
            doc["ground_truth_errors"] = finite_or_null(self.bundle_errors)
        return doc


def calibrate_sequence(
    path: str | Path,
    cameras: list[str] | None = None,
    frontend: str = "network",
    checkpoint: str | Path | None = None,
    device: str = "cpu",
    motion: str = "multi",
    solver: str = "exact",
    forgetting: float = 1.0,
    scale: str = "normalise",
    refine: bool | str = "unobservable",
    max_frames: int | None = None,
    intrinsics: str | None = None,
    align: bool | None = None,
    rig_align: bool | None = None,
    progress: bool | None = None,
    on_frame=None,
) -> ImageCalibration:
    """Calibrate cameras 1..C-1 of the sequence at ``path`` against camera 0 (the first of ``cameras``).

    frontend: ``network`` (the pose network of ``checkpoint``, default the shipped one) or ``opencv``.
    motion, solver, forgetting, refine: the head's (see :class:`OnlineCalibrator`; ``refine`` defaults to
    ``"unobservable"``: a monocular front end's translation directions must not move an observable rotation, see
    :data:`~ocalib.calib.solve.REFINE_MODES`); scale: see :class:`OnlineCalibrationNet` (the default,
    ``normalise``, was measured better on the held-out rigs: docs/results-calibrate.md). align: refine the network's motions
    by direct photometric alignment (:class:`~ocalib.frontend.align.StreamAligner`; None: with the
    network front end, measured better on every held-out rig: docs/results-calibrate.md). rig_align: camera k's aligned
    translation is re-aligned under the rig's rotation (:class:`OnlineCalibrationNet`; None: with ``align``,
    measured better on the held-out cars: docs/results-calibrate.md). max_frames: use only the first
    frames. on_frame(t, estimate): called after every frame (e.g. TensorBoard). progress: a tqdm bar with the
    current estimate (None: on a terminal).
    """
    if frontend not in FRONTENDS:
        raise InputError(f"unknown front end {frontend!r}: {', '.join(FRONTENDS)}")
    align = frontend == "network" if align is None else align
    if align and frontend != "network":
        raise InputError("align refines the pose network's motions; the OpenCV front end has its own bundle adjustment")
    rig_align = align if rig_align is None else rig_align
    if rig_align and not align:
        raise InputError("rig-align re-aligns the photometrically aligned motions: it needs align")
    if not 0 < forgetting <= 1:
        raise InputError(f"forgetting must be in (0, 1], got {forgetting}")
    sequence = open_sequence(path, cameras, intrinsics)
    if len(sequence.cameras) < 2:
        raise InputError(
            f"{path}: calibration needs at least two cameras, the sequence has {', '.join(sequence.names)}"
        )
    frames = len(sequence) if max_frames is None else min(len(sequence), max_frames)
    if frames < MIN_FRAMES:
        raise InputError(f"{path}: {frames} frames is too short to calibrate (at least {MIN_FRAMES})")
    check_motion(sequence)
    if frontend == "network":
        from ocalib.models import load_model

        model = load_model(checkpoint).to(device)
        views = [model_view(c, model.height, model.width) for c in sequence.cameras]
        frames_in = FrameImages(sequence, views)
        net = OnlineCalibrationNet(
            model,
            len(sequence.cameras),
            motion=motion,
            solver=solver,
            forgetting=forgetting,
            refine=refine,
            scale=scale,
            intrinsics=np.stack([v.K for v in views]),
            align=align,
            rig_align=rig_align,
        ).to(device)
        step = _network_step(net, device)
    else:
        frames_in = RigStream(sequence, size=sequence.cameras[0].size)
        head = OnlineCalibrator(
            len(sequence.cameras), motion=motion, solver=solver, forgetting=forgetting, refine=refine
        )
        step = _opencv_step(head)

    final, trace, trajectory = _stream(frames_in, frames, step, progress, on_frame)
    C = len(sequence.cameras)
    times = sequence.times[:frames] if sequence.times is not None else np.arange(frames, dtype=np.float64)
    trace = {"frame": np.arange(frames), "time": times} | trace
    rig = RigPoses(
        files=sequence.names,
        poses=trajectory,
        times=times,
        lines=np.tile(np.arange(1, frames + 1)[:, None], (1, C)),
        time_offsets=[None] * C,
    )
    settings = {
        "frontend": frontend,
        "checkpoint": None if frontend != "network" else str(checkpoint or "default"),
        "align": align,
        "rig_align": rig_align,
        "motion": motion,
        "solver": solver,
        "forgetting": forgetting,
        "refine": refine,
        "scale": scale,
        "frames": frames,
        "max_dt": None,
        "sequence": str(path),
    }
    if align:  # motions whose photometric correction was accepted, per camera (frame 0 has none)
        settings["aligned_frames"] = dict(zip(sequence.names, net.aligned[0].tolist()))
    run = CalibrationRun(rig, final, trace, settings, [])
    run.warnings = run_warnings(run) + [
        f"{name}: the photometric alignment kept the network's motion on {frames - 1 - n} of {frames - 1} frames "
        "(textureless images, wrong intrinsics or a poor depth network?)"
        for name, n in settings.get("aligned_frames", {}).items()
        if n < ALIGNED_WARNING * (frames - 1)
    ]
    run.warnings += planar_advice(frontend, final, sequence.names)
    errors = None
    extrinsics = [cam.T_cam0_cam for cam in sequence.cameras]
    if all(T is not None for T in extrinsics):
        truth = None
        if all(cam.poses is not None for cam in sequence.cameras):
            truth = np.stack([cam.poses[:frames] for cam in sequence.cameras], 1)
        errors = extrinsic_errors(final, np.stack(extrinsics), trajectory, truth)
    return ImageCalibration(run, errors, None if errors is None else np.stack(extrinsics[1:]), sequence)


def planar_advice(frontend: str, estimate: Calibration, names: list[str]) -> list[str]:
    """A warning per camera k >= 1 of rig 0 calibrated on planar motion by the network front end, where OpenCV VO was
    measured better (:data:`PLANAR_ADVICE`)."""
    if frontend != "network":
        return []
    return [f"{name}: {PLANAR_ADVICE}" for name, planar in zip(names[1:], estimate.planar_motion[0].tolist()) if planar]


def _network_step(net: OnlineCalibrationNet, device: str):
    def step(images: torch.Tensor) -> tuple[Calibration, torch.Tensor]:
        out = net(images.to(device, non_blocking=True))
        return out, net.trajectory[0]

    return step


def _opencv_step(head: OnlineCalibrator):
    from ocalib.frontend import OpenCVOdometry

    odometry = []

    def step(frame: dict) -> tuple[Calibration, torch.Tensor]:
        if not odometry:
            odometry.extend(OpenCVOdometry(K.double().numpy()) for K in frame["K"])
        images = (frame["image"].permute(0, 2, 3, 1).numpy() * 255).round().astype(np.uint8)
        for vo, image in zip(odometry, images):
            vo.step(image)
        poses = torch.from_numpy(np.stack([vo.pose for vo in odometry]))
        return head(poses), poses

    return step


def _stream(dataset, frames: int, step, progress, on_frame):
    """Run ``step`` on items 0..frames-1 of ``dataset`` -> (last estimate, trace columns, trajectories (T, C, 4, 4))."""
    loader = DataLoader(
        torch.utils.data.Subset(dataset, range(frames)), batch_size=None, num_workers=1, prefetch_factor=4
    )
    chunks, pending, trajectory = [], [], []
    with (
        torch.inference_mode(),
        tqdm(total=frames, unit="frame", disable=None if progress is None else not progress, desc="calibrating") as bar,
    ):
        for t, frame in enumerate(loader):
            out, poses = step(frame)
            pending.append(out)
            trajectory.append(poses)
            if on_frame is not None:
                on_frame(t, out)
            if len(pending) == TRACE_EVERY or t == frames - 1:
                chunks.append({k: v.cpu() for k, v in trace_rows(stack_estimates(pending)).items()})
                bar.update(len(pending))
                last, pending = pending[-1], []
                bar.set_postfix_str(progress_text(last), refresh=False)
    trace = {k: torch.cat([c[k] for c in chunks]).double().numpy() for k in chunks[0]}
    values = {f.name: getattr(last, f.name) for f in fields(Calibration)}
    last = Calibration(**{k: None if v is None else v.cpu() for k, v in values.items()})
    return last, trace, torch.stack(trajectory).cpu().double().numpy()
