"""``ocalib calibrate-poses CAM0 CAM1 [CAM2 ...]``: rig extrinsics from the pose files of any VO/SLAM system.

Convention: the result is the pose of camera k in camera 0's frame (``p_cam0 = R p_camk + t``, camera-0
units) and the scale that multiplies camera-k units into camera-0 units; a time offset is added to
camera k's timestamps to put them on camera 0's clock.
"""

from __future__ import annotations

import argparse
import json
import sys

from ocalib.cli.calibrate import REFINE_CHOICES


def add_parser(subparsers, name: str) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        name,
        help="calibrate a rig from per-camera pose files (KITTI, TUM or EuRoC / ASL CSV)",
        description=(
            "Calibrate cameras 1..K against camera 0 from each camera's trajectory (KITTI: 12 numbers a line; "
            "TUM: t tx ty tz qx qy qz qw; EuRoC / ASL CSV: t[ns] px py pz qw qx qy qz ...). Prints a summary; writes "
            "the result JSON, a per-frame trace and a plot."
        ),
    )
    p.add_argument("files", nargs="+", metavar="CAM", help="pose files, camera 0 (the reference) first")
    p.add_argument(
        "--format",
        choices=("auto", "kitti", "tum", "euroc"),
        default="auto",
        help="pose file format: KITTI (3x4 a line), TUM (t tx ty tz qx qy qz qw) or EuRoC / ASL CSV "
        "(t[ns] px py pz qw qx qy qz ...); default auto: from the header and the numbers on the first "
        "pose line",
    )
    p.add_argument(
        "--times",
        nargs="+",
        metavar="FILE",
        help="KITTI times.txt files, one per pose file, to pair poses by timestamp",
    )
    p.add_argument("--out", metavar="JSON", help="write the result JSON here")
    p.add_argument("--trace", metavar="CSV", help="write the per-frame estimates and observability here")
    p.add_argument("--plot", metavar="PNG", help="plot the per-frame estimates here")
    p.add_argument(
        "--motion",
        choices=("first", "consecutive", "multi", "absolute"),
        default="multi",
        help="motion pairs: against frame 0, consecutive frames, or gaps of 1, 2, 4, 8 and 16 frames weighted by "
        "their noise (default, for VO / SLAM trajectories); absolute: every pose on its own (AX = YB), for poses "
        "whose errors are independent from pose to pose (a calibration target seen by each camera, motion "
        "capture; see --pose-error)",
    )
    p.add_argument(
        "--pose-error",
        choices=("camera", "world"),
        help="with --motion absolute: where the poses' translation error lives: camera (default: the "
        "target's position in the camera, as PnP gives it) or world (the camera's position, as motion "
        "capture gives it); the wrong one costs about 2x in translation",
    )
    p.add_argument(
        "--solver",
        choices=("exact", "rls", "batch"),
        default="exact",
        help="exact on-line least squares (default), the paper's RLS, or one batch solve",
    )
    p.add_argument(
        "--forgetting",
        type=float,
        default=1.0,
        metavar="L",
        help="forgetting factor in (0, 1]: old frames weigh L per frame (default 1)",
    )
    p.add_argument(
        "--time-offset",
        nargs="+",
        metavar="SECONDS|auto",
        help="clock offset added to camera k's timestamps (t0 = tk + offset): one value for all cameras "
        "or one per camera; 'auto' estimates it from the angular speeds (needs timestamps)",
    )
    p.add_argument(
        "--refine",
        choices=REFINE_CHOICES,
        default="always",
        help="joint refinement of the closed form by the translation rows: always (default, for SLAM or "
        "metric poses), only where the rotation rows leave the rotation unobservable (for monocular VO, "
        "whose translation directions are biased), or never",
    )
    p.add_argument(
        "--sync",
        choices=("interpolate", "nearest"),
        default="interpolate",
        help="with timestamps: interpolate camera k's poses at camera 0's stamps (rotation by SLERP, "
        "position linearly; default), or take the nearest pose",
    )
    p.add_argument(
        "--max-dt",
        type=float,
        metavar="S",
        help="with timestamps: nearest: pair poses at most S seconds apart (default half a camera-0 frame "
        "period); interpolate: across camera-k gaps of at most 2 S (default S: 1.25 camera-k frame periods, "
        "so one dropped frame is bridged)",
    )
    return p


def run(args) -> int:
    from ocalib.calib.pipeline import calibrate_files
    from ocalib.errors import InputError

    if args.solver == "batch" and args.plot:
        raise InputError("--plot shows per-frame estimates, which --solver batch does not make; use exact or rls")
    if args.max_dt is not None and not args.max_dt > 0:
        raise InputError(f"--max-dt must be a positive number of seconds, got {args.max_dt}")
    result = calibrate_files(
        args.files, args.format, args.times, args.time_offset, args.max_dt,
        args.motion, args.solver, args.forgetting, REFINE_CHOICES[args.refine], progress=None, sync=args.sync,
        pose_error=args.pose_error,
    )  # fmt: skip
    doc = result.result_json()
    if args.out:
        with open(args.out, "w") as f:
            json.dump(doc, f, indent=2)
    if args.trace:
        result.write_trace(args.trace)
    if args.plot:
        from ocalib.viz.calibration import plot_trace

        plot_trace(result.trace, args.files[1:], args.plot)
    print(summary(doc))
    for w in doc["warnings"]:
        print(f"warning: {w}", file=sys.stderr)
    return 0


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
    import numpy as np

    from ocalib.viz.calibration import rotation_vector, rpy_deg

    pm = lambda v, s: f"{v:+.4f}" + (f" ± {s:.2g}" if s is not None else " ± ?(unobservable)")  # noqa: E731
    s = doc["settings"]
    lines = [f"reference: {doc['reference']}  ({s['frames']} frames, solver {s['solver']}, motion {s['motion']})"]
    for e in doc["extrinsics"]:
        obs = e["observability"]
        if None in e["quaternion_wxyz"]:  # absolute poses, rotation unobservable: no estimate
            lines += [
                f"{e['camera']}: {e['frames_used']} frames used, {e['frames_rejected']} rejected",
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
        lines += [
            f"{e['camera']}: {e['frames_used']} frames used, {e['frames_rejected']} rejected{offset}",
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
