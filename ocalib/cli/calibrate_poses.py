"""``ocalib calibrate-poses CAM0 CAM1 [CAM2 ...]``: rig extrinsics from the pose files of any VO/SLAM system.

Convention: the result is the pose of camera k in camera 0's frame (``p_cam0 = R p_camk + t``, camera-0
units) and the scale that multiplies camera-k units into camera-0 units; a time offset is added to
camera k's timestamps to put them on camera 0's clock.
"""

from __future__ import annotations

import argparse
import json

from ocalib.cli.options import MOTIONS_HELP, add_head_arguments, head_options

ABSOLUTE_HELP = (
    "every pose on its own (AX = YB), for poses whose errors are independent from pose to pose (a calibration "
    "target seen by each camera, motion capture; see --pose-error)"
)


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
        "--pose-error",
        choices=("camera", "world"),
        help="with --motion absolute: where the poses' translation error lives: camera (default: the "
        "target's position in the camera, as PnP gives it) or world (the camera's position, as motion "
        "capture gives it); the wrong one costs about 2x in translation",
    )
    add_head_arguments(
        p,
        refine="always",
        motions=MOTIONS_HELP | {"absolute": ABSOLUTE_HELP},
        solvers={
            "exact": "exact on-line least squares (default)",
            "rls": "the paper's RLS",
            "batch": "one batch solve of all frames",
        },
    )
    p.add_argument(
        "--time-offset",
        nargs="+",
        metavar="SECONDS|auto",
        help="clock offset added to camera k's timestamps (t0 = tk + offset): one value for all cameras "
        "or one per camera; 'auto' estimates it from the angular speeds (needs timestamps)",
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
    from ocalib.calib.poses.pipeline import calibrate_files
    from ocalib.calib.poses.report import print_warnings, summary
    from ocalib.errors import InputError

    if args.solver == "batch" and args.plot:
        raise InputError("--plot shows per-frame estimates, which --solver batch does not make; use exact or rls")
    if args.max_dt is not None and not args.max_dt > 0:
        raise InputError(f"--max-dt must be a positive number of seconds, got {args.max_dt}")
    result = calibrate_files(
        args.files, head_options(args), progress=None,
        format=args.format, times=args.times, time_offset=args.time_offset, max_dt=args.max_dt, sync=args.sync,
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
    print_warnings(doc)
    return 0
