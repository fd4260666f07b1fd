"""``ocalib export RIG_JSON --format kalibr|ros|urdf|colmap``: a calibration in another tool's format.

Convention: the result JSON's ``T_cam0_camk`` (``p_cam0 = R p_camk + t``), camera 0 the reference, translations in
its units; each format's own conventions are :mod:`ocalib.io.export`'s.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ocalib.io.export import FORMATS


def add_parser(subparsers, name: str) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        name,
        help="write a result JSON's extrinsics for Kalibr, ROS 2, URDF or COLMAP",
        description=(
            "Write the extrinsics of a result JSON (ocalib calibrate / calibrate-poses --out) in another tool's "
            "format; the cameras' K, size and lens come from a rig.yaml (--rig, or the calibrated sequence's)."
        ),
    )
    p.add_argument("result", metavar="RIG_JSON", help="the result JSON")
    p.add_argument(
        "--format",
        required=True,
        choices=FORMATS,
        help="; ".join(f"{key}: {fmt.help}" for key, fmt in FORMATS.items()),
    )
    p.add_argument("--out", metavar="FILE", help="write it here (default: standard output)")
    p.add_argument(
        "--rig",
        metavar="RIG_YAML",
        help="the rig.yaml with the cameras' intrinsics (default: DIR/rig.yaml of the sequence the JSON names)",
    )
    p.add_argument(
        "--frame-prefix", default="cam", metavar="PREFIX", help="frames are PREFIX0 (the reference), PREFIX1, ... (cam)"
    )
    return p


def run(args) -> int:
    from ocalib.data.rig import read_rig_yaml
    from ocalib.errors import InputError
    from ocalib.io.export import read_result, with_intrinsics

    rig, fmt = read_result(args.result), FORMATS[args.format]
    rig_yaml = Path(args.rig) if args.rig else sequence_rig(rig.sequence)
    if rig_yaml is not None:
        rig = with_intrinsics(rig, read_rig_yaml(rig_yaml).cameras, rig_yaml)
    if fmt.needs_intrinsics and not rig.has_intrinsics:
        raise InputError(f"{args.result}: --format {args.format} needs the cameras' intrinsics: give --rig rig.yaml")
    text = fmt.write(rig, args.frame_prefix)
    if args.out:
        Path(args.out).write_text(text)
    else:
        sys.stdout.write(text)
    for note in rig.notes:
        print(f"ocalib export: note: {note}", file=sys.stderr)
    return 0


def sequence_rig(sequence: str | None) -> Path | None:
    """``DIR/rig.yaml`` of the calibrated sequence ``DIR`` that a result JSON names, where it is there; else None."""
    path = None if sequence is None else Path(sequence, "rig.yaml")
    return path if path is not None and path.is_file() else None
