"""``ocalib predict --sequence DIR --out OUT``: depth maps and trajectories of an ego-motion model.

Convention: ``OUT/<camera>/poses.txt`` (KITTI) holds camera-to-first-frame poses chained from the
frame-to-frame motions ``T_{t-1,t}`` (frame 0 the identity), in network units;
``OUT/<camera>/depth/000000.npy`` float32 (H, W) depth at the model's resolution, network units;
``OUT/<camera>/K.txt`` the intrinsics of that view (see :mod:`ocalib.inference.export`).
"""

from __future__ import annotations

import argparse


def add_parser(subparsers, name: str) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        name,
        help="predict depth maps and camera trajectories of a sequence with an ego-motion model",
        description="Run an ego-motion model over every camera of a sequence (rig layout, KITTI raw or odometry, "
        "SfMLearner, image folder): writes OUT/<camera>/depth/NNNNNN.npy (float32 depth, network units, at the "
        "model's resolution), OUT/<camera>/poses.txt (KITTI, camera-to-first-frame) and OUT/<camera>/K.txt. "
        "Images are centre-cropped to the model's aspect ratio and resized to its resolution.",
    )
    add_model_arguments(p)
    p.add_argument("--out", required=True, metavar="OUT", help="output folder")
    p.add_argument("--no-depth", action="store_true", help="poses only (skips the depth network)")
    return p


def add_model_arguments(p: argparse.ArgumentParser) -> None:
    """Options shared by ``predict`` and ``evaluate``."""
    p.add_argument("--sequence", required=True, metavar="DIR", help="the sequence folder")
    p.add_argument(
        "--checkpoint",
        metavar="CKPT",
        help="ego-motion model (ocalib model file or training .ckpt; default: the shipped one)",
    )
    p.add_argument("--cameras", nargs="+", metavar="NAME", help="cameras to use (default: all)")
    p.add_argument("--intrinsics", metavar="FILE", help="intrinsics file for layouts without one (image folders)")
    p.add_argument("--device", default="cpu", help="torch device (cpu, cuda, cuda:1, ...)")
    p.add_argument(
        "--batch-size", type=int, default=8, metavar="N", help="frames per forward pass, all cameras (default 8)"
    )
    p.add_argument("--workers", type=int, default=1, metavar="N", help="image-reading processes (default 1; 0: none)")
    p.add_argument(
        "--align",
        action="store_true",
        help="refine each motion by direct photometric alignment on the network's depth of the previous "
        "frame (about 25 ms a camera and frame on 2 CPU cores)",
    )
    p.add_argument(
        "--flip",
        action="store_true",
        help="average each depth map with that of the mirrored image (test-time flipping: abs rel 0.001-0.007 "
        "lower on the held-out synthetic cameras, twice the depth network's time)",
    )


def open_inputs(args):
    """(model, sequence) of the parsed arguments (the device checked by the command line); errors are InputErrors
    naming the file."""
    from ocalib.data.layout import open_sequence
    from ocalib.errors import InputError
    from ocalib.models import load_model

    if args.workers < 0:
        raise InputError(f"--workers must be >= 0, got {args.workers}")
    sequence = open_sequence(args.sequence, args.cameras, args.intrinsics)
    if len({len(c) for c in sequence.cameras}) > 1:  # cameras with frames of their own: the model takes them paired
        from ocalib.data.synchronise import synchronise

        sequence = synchronise(sequence, [0.0] * len(sequence.cameras))
    return load_model(args.checkpoint), sequence


def predict_options(args, depth: bool = True):
    """The :class:`~ocalib.inference.predict.PredictOptions` of the parsed model arguments."""
    from ocalib.inference.predict import PredictOptions

    return PredictOptions(args.batch_size, depth, args.workers, args.align, args.flip)


def run(args) -> int:
    from ocalib.inference.export import save_predictions

    model, sequence = open_inputs(args)
    options = predict_options(args, depth=not args.no_depth)
    poses = save_predictions(model, sequence, args.out, args.device, options, progress=None)
    for name, P in poses.items():
        length = sum(float(((b - a) ** 2).sum() ** 0.5) for a, b in zip(P[:-1, :3, 3], P[1:, :3, 3]))
        print(f"{name}: {len(P)} frames, path length {length:.4g} (network units) -> {args.out}/{name}/")
    return 0
