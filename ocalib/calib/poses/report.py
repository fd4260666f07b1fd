"""The calibration's report: the result JSON, the per-frame trace, the warnings and the printed summary.

:class:`CalibrationRun` holds a calibration's outcome (``calibrate-poses`` and ``calibrate`` alike) and writes its
JSON and trace; :func:`run_warnings` reads the input and the estimate for what a user must know; :func:`summary`
and :func:`errors_table` print a result JSON and its ground-truth errors.

Convention: ``T_cam0_camk`` (``p_cam0 = R p_camk + t``, camera-0 units), the scale that multiplies camera-k units
into camera-0 units, quaternions (w, x, y, z); angles in degrees.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from ocalib.calib.drivers.absolute import ROTATION_GAP_MIN
from ocalib.calib.drivers.change import ChangeTest
from ocalib.calib.drivers.result import Calibration
from ocalib.calib.stages.rotation import ROTATION_OBSERVABLE_MIN_SV, ROTATION_OBSERVABLE_SIGNIFICANCE
from ocalib.geometry.angles import rotation_vector, rpy_deg
from ocalib.io.poses import describe_invalid

if TYPE_CHECKING:
    from ocalib.calib.poses.pipeline import RigPoses

# A translation residual above this share of camera 0's motion (RMS) is reported. Measured on the held-out rigs
# (docs/calibnet.md): true poses with VO-like drift 0.002-0.005 leave 1-12 %, OpenCV VO 11-60 %, the aligned pose
# network 26-49 % (81-98 % before alignment); the translations of the last two are 0.4-25 baselines off.
TRANSLATION_RESIDUAL_WARNING = 0.15
UNPAIRED_WARNING = 0.1  # camera-0 stamps left without a camera-k pose inside its span, as a share of the frames kept
# Whose estimate an extrinsic of the result JSON is, by its "source" (none: the on-line head's)
SOURCES = {"bundle_adjustment": "the rig bundle adjustment", "rig_estimator": "the on-line rig estimator"}
# The per-camera keys of the result JSON, in their documented order (docs/guide.md: the result).
CAMERA_KEYS = (
    "camera", "rotation", "quaternion_wxyz", "translation", "scale", "time_offset", "frames_used",
    "frames_rejected", "rotation_std_deg", "translation_std", "scale_std", "observability",
)  # fmt: skip


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
    changes: list[dict] = field(default_factory=list)

    def result_json(self) -> dict:
        """The result JSON (docs/guide.md: the result), plus ``settings``, ``time_offset_estimates`` and ``warnings``."""
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
                "rotation_residual_ratio": q.residual_ratio,
            }
            for f, o, q in zip(self.rig.files, self.rig.time_offsets, self.rig.offset_quality)
            if q is not None
        ]
        if estimated:
            out["time_offset_estimates"] = estimated
        out["changes"] = self.changes
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
            "rig_quaternion": ["rig_qw", "rig_qx", "rig_qy", "rig_qz"], "rig_translation": ["rig_tx", "rig_ty", "rig_tz"],
            "rig_translation_std": ["rig_tx_std", "rig_ty_std", "rig_tz_std"],
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


def untested_warnings(run: CalibrationRun, test: ChangeTest = ChangeTest()) -> list[str]:
    """A line per camera whose extrinsic the change ``test`` never tested: the on-line head's rotation 1-sigma never
    under the test's ``settled_deg`` after its warm-up (its estimate is no reference for the residuals), or the
    stream ended before the test's first decision after it settled (:meth:`ChangeTest.first_decision`)."""
    std = run.trace.get("rotation_std_deg")
    if std is None or len(std) <= test.warmup:
        return []
    out = []
    for f, s in zip(run.rig.files[1:], np.moveaxis(std[test.warmup - 1 :], 1, 0)):
        settled = np.flatnonzero((s <= test.settled_deg).all(1))
        reference = int(settled[0]) + test.warmup - 1 if len(settled) else None
        if reference is None:
            out.append(f"{f}: a change of its extrinsic could not be tested: the on-line head's rotation 1-sigma never "
                       f"came under {test.settled_deg} deg (the change test's reference must be that close)")  # fmt: skip
        elif (first := test.first_decision(reference)) >= len(std):
            out.append(f"{f}: a change of its extrinsic could not be tested: the stream ends at frame {len(std) - 1}, "
                       f"before the change test's first decision at frame {first} (its head settled at frame "
                       f"{reference}; the test compares a window of {max(test.windows)} frames with at least "
                       f"{test.min_history} before it)")  # fmt: skip
    return out


def run_warnings(run: CalibrationRun) -> list[str]:
    """Readable warnings about the input and the final estimate."""
    rig, e = run.rig, run.final
    out = [msg for c, f in enumerate(rig.files) if (msg := describe_invalid(f, rig.valid[:, c], rig.lines[:, c]))]
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
                f"{ROTATION_OBSERVABLE_SIGNIFICANCE:g}, see ocalib.calib.stages.rotation). The motion rotates too "
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
                f"{f}: {rejected} of {frames} frames rejected by the on-line head (an invalid pose of camera 0 or "
                "this camera, or motions failing the screw-congruence gate)"
            )
    for c in run.changes:
        out.append(
            f"{c['camera']}: its extrinsic changed at frame {c['frame']} (noticed at frame {c['detected']}): "
            f"{c['rotation_change_deg']:.2f} deg, {c['translation_change']:.3g} in camera 0's units; the on-line head "
            "restarted there and its estimate follows the new extrinsic"
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


def residual_text(residuals: dict) -> str:
    """``rotation 0.12 deg, translation 3.4 % of camera 0's motion`` (``?`` where undefined), or a bundle
    adjustment's ``reprojection 0.38 px``."""
    if "reprojection_px" in residuals:
        px = residuals["reprojection_px"]
        return f"reprojection {'?' if px is None else f'{px:.3g} px'} (bundle adjustment, mean)"
    rot, tr = residuals["rotation_deg"], residuals["translation_relative"]
    return (
        f"rotation {'?' if rot is None else f'{rot:.3g} deg'}, translation "
        f"{'?' if tr is None else f'{100 * tr:.3g} %'} of camera 0's motion"
    )


def summary(doc: dict) -> str:
    """Readable summary of a result JSON: per camera, rotation, translation, scale with 1-sigma and flags."""
    pm = lambda v, s: f"{v:+.4f}" + (f" ± {s:.2g}" if s is not None else " ± ?(unobservable)")  # noqa: E731
    s = doc["settings"]
    lines = [f"reference: {doc['reference']}  ({s['frames']} frames, solver {s['solver']}, motion {s['motion']})"]
    if "frontend_choice" in s:  # calibrate --frontend auto
        residuals = s["frontend_choice"]["congruence_residual"].items()
        tried = ", ".join(f"{name} " + ("n/a" if r is None else f"{r:.3f}") for name, r in residuals)
        lines.append(f"front end: {s['frontend']}, chosen on the first {s['frontend_choice']['frames']} frames by "
                     f"the rig's rotation angles (congruence residual {tried}; 0: every camera turns alike)")  # fmt: skip
    elif "frontend" in s:  # calibrate --frontend NAME: the one given
        lines.append(f"front end: {s['frontend']} (--frontend {s['frontend']})")
    for e in doc["extrinsics"]:
        obs = e["observability"]
        if None in e["quaternion_wxyz"]:  # absolute poses, rotation unobservable: no estimate
            lines += [
                f"{e['camera']}: {_frames_text(e)}",
                "  no estimate: ROTATION UNOBSERVABLE (see the warnings)",
            ]
            continue
        q = np.array(e["quaternion_wxyz"])
        rv = np.rad2deg(rotation_vector(q))
        angle = float(np.linalg.norm(rv))
        axis = rv / angle if angle > 0 else np.array([1.0, 0.0, 0.0])
        rstd = e["rotation_std_deg"] or [None] * 3
        flags = [name for name, on in (
            ("ROTATION UNOBSERVABLE", not obs["rotation_observable"] and not obs["planar_motion"]),
            ("PLANAR MOTION (rotation from the translation constraint)", obs["planar_motion"]),
            (f"{len(obs['unobservable_translation_directions'])} translation direction(s) unobservable",
             bool(obs["unobservable_translation_directions"])),
        ) if on]  # fmt: skip
        offset = "" if e["time_offset"] is None else f", time offset {e['time_offset']:+.6f} s"
        source = SOURCES.get(e.get("source"), "the on-line head")
        lines += [
            f"{e['camera']}: from {source}; {_frames_text(e)}{offset}",
            "  rotation roll/pitch/yaw (deg, R = Rz Ry Rx): "
            + ", ".join(f"{v:+.3f}" for v in rpy_deg(q))
            + f"; axis-angle {angle:.3f} deg about [{', '.join(f'{v:+.4f}' for v in axis)}]"
            + "; std about x/y/z (deg): "
            + ", ".join("?" if v is None else f"{v:.2g}" for v in rstd),
            "  translation: "
            + ", ".join(pm(v, sd) for v, sd in zip(e["translation"], e["translation_std"] or [None] * 3)),
            f"  scale: {e['scale']:+.4f} (camera k's front-end units into camera 0's, through the one rig trajectory)"
            if e.get("source") == "bundle_adjustment"
            else f"  scale: {pm(e['scale'], e['scale_std'])}",
            "  residuals (RMS): " + residual_text(e["residuals"]),
            f"  flags: {', '.join(flags) if flags else 'none'}",
        ]
    return "\n".join(lines)


def _frames_text(e: dict) -> str:
    """What ``frames_used`` / ``frames_rejected`` of camera JSON ``e`` count, said as such: the bundle adjustment's
    keyframes (registered or not) where it gave the result, else the on-line head's frames (used or rejected)."""
    if e.get("source") == "bundle_adjustment":
        total = e["frames_used"] + e["frames_rejected"]
        return f"{e['frames_used']} of {total} keyframes registered in the bundle adjustment"
    return f"the on-line head used {e['frames_used']} frames and rejected {e['frames_rejected']}"


def print_warnings(doc: dict) -> None:
    """The result's warnings (translation not supported, rejected frames, ...) on stderr, one line each."""
    for w in doc["warnings"]:
        print(f"warning: {w}", file=sys.stderr)


def _finite(value, spec: str, undefined: str) -> str:
    """``value`` formatted by ``spec``, or ``undefined`` where it is not a finite number (no NaN is printed)."""
    return format(value, spec) if value is not None and math.isfinite(value) else undefined


def errors_table(errors: list[dict], cameras: list[str], what: str | None = None) -> str:
    """The ground-truth errors, one line per camera (``what``: whose, e.g. the on-line head's). A figure the
    estimate does not define (a translation direction with fewer than two observable components, a baseline of
    zero) is said as ``n/a`` with the reason, never as a NaN."""
    lines = ["errors against the ground truth" + (f", {what}:" if what else ":")]
    for e in errors:
        direction = e["translation_direction_error_deg"]
        if direction is not None and math.isfinite(direction):
            direction_text = f"{direction:.2f} deg" + (" (in the plane)" if e["compared_in_plane"] else "")
        elif e["compared_in_plane"]:
            direction_text = "n/a (fewer than two of its components observable)"
        else:
            direction_text = "n/a (a zero translation has no direction)"
        rotation = _finite(e["rotation_error_deg"], ".3f", "n/a (no estimate)")
        text = f"  {cameras[e['camera']]}: rotation {rotation}{' deg' * rotation[0].isdigit()}, translation direction "
        text += direction_text
        if "translation_error_rel_baseline" in e:
            relative = _finite(e["translation_error_rel_baseline"], ".1%", "n/a")
            if relative[0].isdigit():
                text += f", translation {e['translation_error']:.3f} m = {relative} of the baseline"
            elif _finite(e["translation_error"], ".3f", ""):
                text += f", translation {e['translation_error']:.3f} m (a zero baseline)"
            else:
                text += ", translation n/a (no direction of it determined)"
            text += (
                ""
                if e["metric_scale"] == 1
                else f" (camera 0 scaled to metres x{_finite(e['metric_scale'], '.3g', 'n/a')})"
            )
        if "scale_true" in e:  # the on-line head's: what the front end's motions held
            text += f", scale {_finite(e['scale'], '.3f', 'n/a')} (true {_finite(e['scale_true'], '.3f', 'n/a')})"
            gains = lambda g: "/".join(_finite(x, ".2f", "n/a") for x in g)  # noqa: E731
            text += (
                f"\n    front-end rotation gain x/y/z (1: unbiased): {cameras[0]} {gains(e['rotation_gain_reference'])}, "
                f"{cameras[e['camera']]} {gains(e['rotation_gain'])}"
            )
            if math.isfinite(e["scale_wander"]):
                text += (
                    f"\n    front-end scale wander against {cameras[0]} {e['scale_wander']:.3f}, lever-arm signal "
                    f"{e['lever_arm_signal']:.3f} ({e['wander_window']}-frame windows; the translation needs the first "
                    "well under the second)"
                )
        lines.append(text)
    return "\n".join(lines)
