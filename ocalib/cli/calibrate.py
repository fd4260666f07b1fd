"""``ocalib calibrate --sequence DIR``: rig extrinsics from the images of a sequence, frame by frame.

Convention: as ``calibrate-poses`` -- the pose of camera k in camera 0's frame (``p_cam0 = R p_camk + t``,
in camera 0's front-end units) and the scale that multiplies camera k's front-end units into camera 0's.
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import replace

from ocalib.cli.options import MOTIONS_HELP, add_frontend_arguments, add_head_arguments, frontend_options, head_options
from ocalib.errors import InputError
from ocalib.rigba.options import DEFAULT_METRIC_NOISE, MAPPERS, BundleOptions


def add_parser(subparsers, name: str) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        name,
        help="calibrate a rig from its image sequence (pose network or OpenCV front end)",
        description="Calibrate cameras 1..K of a sequence (rig layout, KITTI raw or odometry, SfMLearner, image "
        "folders) against camera 0 from the images alone, on-line: each frame the front end's ego-motion "
        "updates the calibration head. Prints the estimate (and its errors when the sequence has ground truth); "
        "writes the JSON of calibrate-poses, a per-frame trace, a plot and TensorBoard scalars.",
    )
    add_source_arguments(p)
    p.add_argument("--cameras", nargs="+", metavar="NAME", help="cameras to use, the reference first (default: all)")
    add_bag_arguments(p)
    add_frontend_arguments(p)
    p.add_argument("--out", metavar="JSON", help="write the result JSON here")
    p.add_argument("--trace", metavar="CSV", help="write the per-frame estimates and observability here")
    p.add_argument("--plot", metavar="PNG", help="plot the per-frame estimates here")
    p.add_argument("--tensorboard", metavar="DIR", help="write per-frame TensorBoard scalars here")
    p.add_argument("--trajectories", metavar="DIR", help="write each camera's front-end trajectory (KITTI) here")
    p.add_argument(
        "--ego-motion",
        metavar="FILE",
        help="keep the front end's ego-motion in FILE, and take it from there when FILE holds this run's (the same "
        "frames, front end, head and ocalib): the same result without running the front end again, e.g. to try "
        "other rig-estimator or bundle-adjustment settings",
    )
    p.add_argument("--device", default="cpu", help="torch device of the network and the head (cpu, cuda)")
    add_head_arguments(
        p,
        refine="unobservable",
        motions=MOTIONS_HELP,
        solvers={"exact": "the exact on-line least squares (default)", "rls": "the paper's RLS"},
    )
    p.add_argument("--max-frames", type=int, metavar="N", help="use only the first N frames")
    p.add_argument("--intrinsics", metavar="FILE", help="intrinsics file for layouts without one (image folders)")
    p.add_argument(
        "--time-offset",
        nargs="+",
        metavar="SECONDS|auto",
        help="cameras without a shared clock: the offset added to camera k's timestamps (t0 = tk + offset), one "
        "value for all cameras or one per camera; 'auto' estimates it from the front end's rotations (a first pass "
        "over the frames). Each camera-0 frame is then paired with every camera's nearest frame in time. Cameras "
        "with their own <name>/times.txt are paired by their stamps even without it",
    )
    ba = p.add_argument_group("rig bundle adjustment (after the on-line pass: the translation from the images)")
    ba.add_argument(
        "--bundle-adjust",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="refine the on-line estimate by a joint bundle adjustment of every camera's features on "
        "COLMAP, one rig trajectory for all cameras (default: on; --no-bundle-adjust skips it)",
    )
    ba.add_argument(
        "--bundle-adjust-every",
        type=int,
        metavar="N",
        help="streaming: run the bundle adjustment after every N frames on the frames so far (features "
        "and matches kept between runs); the JSON holds each run",
    )
    ba.add_argument(
        "--keyframe-step",
        type=int,
        default=BundleOptions.keyframe_step,
        metavar="K",
        help=f"the bundle adjustment uses every K-th frame (default {BundleOptions.keyframe_step})",
    )
    ba.add_argument(
        "--cross-camera",
        action="store_true",
        help="also match features between cameras (for cameras that share a view, e.g. a stereo pair)",
    )
    ba.add_argument("--mapper", choices=MAPPERS, default="global", help="COLMAP mapper (default global)")
    ba.add_argument(
        "--metric-trajectory",
        metavar="FILE|sequence",
        help="camera 0's trajectory in metres (KITTI: one pose a frame; TUM or EuRoC: met at the "
        "sequence's timestamps), e.g. wheel odometry or GNSS: the translation is then in metres; 'sequence': the "
        "sequence's own (KITTI raw's OXTS packets, KITTI odometry's poses, a rig folder's <camera>/poses.txt)",
    )
    ba.add_argument(
        "--metric-noise",
        type=float,
        metavar="METRES",
        help="the metric trajectory's noise per axis: its positions are priors so weighed in the on-line rig "
        f"estimator's window (default {DEFAULT_METRIC_NOISE}; the rig's poses are solved with the images) and in the bundle adjustment "
        "(default: its reconstruction is only scaled to it); 0: its poses held fixed in both, for an exact "
        "trajectory (the bundle adjustment refuses it, with a warning, where the images disagree with them)",
    )
    ba.add_argument("--colmap-workspace", metavar="DIR", help="keep the COLMAP workspace (database, model) here")
    ba.add_argument(
        "--repeatable",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="COLMAP on one thread (default): the same input gives the same extrinsic bit for bit; "
        "--no-repeatable runs it on every core, faster, and the result then moves from run to run",
    )
    ba.add_argument(
        "--online-rig",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="with --metric-trajectory: run the on-line rig estimator as the stream goes (the whole extrinsic in "
        "metres every keyframe, and a camera that moves mid-run noticed); default on",
    )
    return p


def add_source_arguments(p: argparse.ArgumentParser) -> None:
    """Where the images come from: ``--sequence`` or ``--bag``."""
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--sequence", metavar="DIR", help="the sequence folder")
    source.add_argument(
        "--bag",
        metavar="BAG",
        help="a ROS bag instead (ROS 1 .bag, ROS 2 folder of .db3 or .mcap), with --topics: its images are extracted "
        "once to a temporary rig folder (--bag-cache keeps it), each camera's K and lens from its camera_info",
    )


def add_bag_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``--bag``."""
    bag = p.add_argument_group("ROS bags (--bag)")
    bag.add_argument(
        "--topics",
        nargs="+",
        metavar="TOPIC",
        help="the image topics (sensor_msgs/Image or CompressedImage), camera 0 first; each camera's CameraInfo is "
        "read from the camera_info topic beside it",
    )
    bag.add_argument(
        "--odometry",
        metavar="TOPIC",
        help="a nav_msgs/Odometry or geometry_msgs/PoseStamped topic in metres: camera 0's metric trajectory (as "
        "--metric-trajectory), through /tf_static from its child_frame_id to camera 0's frame_id where it is there",
    )
    bag.add_argument(
        "--odometry-to-cam0",
        nargs=7,
        type=float,
        metavar=("X", "Y", "Z", "QX", "QY", "QZ", "QW"),
        help="camera 0's pose in the odometry's frame (metres; ROS's quaternion order), where /tf_static lacks it "
        "(default: the identity, said in a warning)",
    )
    bag.add_argument(
        "--bag-cache", metavar="DIR", help="extract the bag's images into DIR (missing or empty) and keep them there"
    )


def run(args) -> int:
    if args.bag is None:
        for option in ("topics", "odometry", "odometry_to_cam0", "bag_cache"):
            if getattr(args, option) is not None:
                raise InputError(f"--{option.replace('_', '-')} is an option of --bag")
        return _calibrate(args)
    import tempfile
    from pathlib import Path

    from ocalib.data.rosbag import extract_bag, pose_matrix

    if not args.topics or len(args.topics) < 2:
        raise InputError(f"{args.bag}: --topics must name at least two image topics, camera 0's first")
    if args.odometry and args.metric_trajectory:
        raise InputError("--odometry and --metric-trajectory both give camera 0's trajectory: give one")
    if args.odometry_to_cam0 is not None and not args.odometry:
        raise InputError("--odometry-to-cam0 needs --odometry")
    to_cam0 = args.odometry_to_cam0
    to_cam0 = None if to_cam0 is None else pose_matrix(to_cam0[:3], to_cam0[3:])
    with tempfile.TemporaryDirectory(prefix="ocalib-bag-") as tmp:
        folder = Path(args.bag_cache) if args.bag_cache else Path(tmp) / "sequence"
        frames = args.max_frames if args.time_offset is None else None  # other clocks: the whole bag
        extract = extract_bag(args.bag, args.topics, folder, args.odometry, to_cam0, args.intrinsics, frames)
        print(
            "\n".join(extract.notes) + ("" if args.bag_cache else " (removed at the end; --bag-cache DIR keeps them)")
        )
        args = argparse.Namespace(**vars(args))
        args.sequence = str(folder)
        if extract.odometry is not None:
            args.metric_trajectory, args.metric_shown = str(extract.odometry), f"{args.bag}: {args.odometry}"
        return _calibrate(args, extract.warnings)


def _calibrate(args, warnings: list[str] = ()) -> int:
    """``calibrate`` on the sequence folder ``args.sequence``; ``warnings`` go first in the result's."""
    from ocalib.calibnet.sequence import open_calibration_sequence

    frontend, head = frontend_options(args), head_options(args)
    _check_numbers(args)
    sequence = open_calibration_sequence(
        args.sequence, args.cameras, args.intrinsics, args.max_frames, args.time_offset, frontend, args.device
    )
    sequence, metric, rig, said = _metric_trajectory(args, sequence)
    from ocalib.calib.poses.report import print_warnings, summary  # here: the input's errors above load no torch
    from ocalib.calibnet.run import calibrate_images

    writer = None
    if args.tensorboard:
        from torch.utils.tensorboard import SummaryWriter

        writer = SummaryWriter(args.tensorboard)

    def on_frame(t, estimate):
        state = rig(t, estimate) if rig is not None else None
        if writer is not None:
            log_frame(writer, t, estimate, state)

    try:
        result = calibrate_images(
            sequence, None, frontend, head, args.device, args.max_frames, progress=None,
            on_frame=on_frame if rig is not None or writer is not None else None, ego_motion=args.ego_motion,
        )  # fmt: skip
    finally:
        if writer:
            writer.close()
    if rig is not None:
        rig.attach(result)
    if args.bundle_adjust:
        from ocalib.calibnet.bundle import refine_calibration
        from ocalib.rigba.options import FeatureOptions, MapperOptions

        threads = 1 if args.repeatable else -1
        options = BundleOptions(
            FeatureOptions(cross_camera=args.cross_camera, threads=threads),
            MapperOptions(kind=args.mapper, threads=threads, metric_noise=args.metric_noise),
            args.keyframe_step,
        )
        refine_calibration(result, metric, options, args.bundle_adjust_every, args.colmap_workspace)
    doc = result.result_json()
    doc["warnings"] = [*warnings, *said, *doc["warnings"]]
    if args.out:
        with open(args.out, "w") as f:
            json.dump(doc, f, indent=2)
    if args.trace:
        result.run.write_trace(args.trace)
    if args.plot:
        from ocalib.viz.calibration import bundle_unobservable, plot_trace

        files, unobservable = result.run.rig.files[1:], bundle_unobservable(doc)
        plot_trace(
            result.run.trace, files, args.plot, truth=result.truth, units=doc["units"], unobservable=unobservable
        )
    if args.trajectories:
        from pathlib import Path

        from ocalib.io.poses import write_kitti

        Path(args.trajectories).mkdir(parents=True, exist_ok=True)
        for c, name in enumerate(result.run.rig.files):
            write_kitti(Path(args.trajectories) / f"{name}.txt", result.run.rig.poses[:, c])
    print(summary(doc))
    print_errors(result)
    print_warnings(doc)
    written = [v for v in (args.out, args.trace, args.plot, args.tensorboard, args.trajectories) if v]
    if written:
        print(f"wrote {', '.join(written)}")
    return 0


def _check_numbers(args) -> None:
    """The numeric options checked before any work."""
    if args.bundle_adjust_every is not None and args.bundle_adjust_every < 1:
        raise InputError(f"--bundle-adjust-every must be at least 1 frame, got {args.bundle_adjust_every}")
    if args.keyframe_step < 1:
        raise InputError(f"--keyframe-step must be at least 1, got {args.keyframe_step}")
    if args.metric_noise is not None and not (0 <= args.metric_noise < math.inf and args.metric_trajectory):
        raise InputError(
            f"--metric-noise must be a number of metres (0: held fixed) with --metric-trajectory, got {args.metric_noise}"
        )


def _metric_trajectory(args, sequence):
    """The --metric-trajectory at the frames of ``sequence`` to calibrate, read before the on-line pass so that bad
    input costs no work -> (the sequence at the frames it meets, its poses there, the on-line rig estimator that runs
    on it, warnings); (sequence, None, None, []) without it."""
    if not args.metric_trajectory:
        return sequence, None, None, []
    if not args.bundle_adjust and not args.online_rig:
        raise InputError(
            "--metric-trajectory is for the on-line rig estimator and the bundle adjustment: drop --no-online-rig "
            "or --no-bundle-adjust"
        )
    from ocalib.data.metric_trajectory import read_metric_trajectory
    from ocalib.rigba.online import OnlineRigOptions
    from ocalib.rigba.stream import OnlineRigStage

    frames = len(sequence) if args.max_frames is None else min(len(sequence), args.max_frames)
    shown = getattr(args, "metric_shown", None)  # what the messages call the trajectory, where not its file's name
    try:
        sequence, metric, said = read_metric_trajectory(args.metric_trajectory, sequence, frames)
    except InputError as err:
        raise InputError(str(err).replace(args.metric_trajectory, shown or args.metric_trajectory)) from None
    said = [line.replace(args.metric_trajectory, shown or args.metric_trajectory) for line in said]
    options = OnlineRigOptions(keyframe_step=args.keyframe_step)
    if args.metric_noise is not None:
        options = replace(options, metric_noise=args.metric_noise)
    rig = OnlineRigStage(sequence, metric, options) if args.online_rig else None
    return sequence, metric, rig, said


def print_errors(result) -> None:
    """The ground-truth errors of each stage that ran, where the sequence has a truth."""
    from ocalib.calib.poses.report import errors_table

    names = result.run.rig.files
    stages = [
        (result.errors, "on-line head"),
        (result.rig_errors, "on-line rig estimator (final state)"),
        (result.bundle_errors, "after the rig bundle adjustment"),
    ]
    ran = [(errors, what) for errors, what in stages if errors]
    for errors, what in ran:
        print(errors_table(errors, names, what if len(ran) > 1 else None))


def log_frame(writer, t: int, estimate, state=None) -> None:
    """TensorBoard scalars of one frame's estimate, camera k of rig 0, and of the on-line rig estimator's
    ``state`` where a keyframe gave one."""
    for k in range(estimate.scale.shape[1]):
        q = estimate.quaternion[0, k].tolist()
        tag = f"camera{k + 1}"
        writer.add_scalar(f"{tag}/rotation_angle_deg", math.degrees(2 * math.atan2(math.hypot(*q[1:]), abs(q[0]))), t)
        for axis, v in zip("xyz", estimate.translation[0, k].tolist()):
            writer.add_scalar(f"{tag}/translation_{axis}", v, t)
        writer.add_scalar(f"{tag}/scale", float(estimate.scale[0, k]), t)
        for i, v in enumerate(estimate.rotation_singular_values[0, k].tolist()):
            writer.add_scalar(f"{tag}/rotation_sv{i}", v, t)
        if state is not None:
            for axis, v, sd in zip("xyz", state.extrinsics[k + 1, :3, 3], state.std[k + 1, 3:]):
                writer.add_scalar(f"{tag}/rig_translation_{axis}_m", float(v), t)
                if math.isfinite(sd):
                    writer.add_scalar(f"{tag}/rig_translation_{axis}_std_m", float(sd), t)
            writer.add_scalar(f"{tag}/rig_change_chi2", float(state.chi2[k + 1]), t)
