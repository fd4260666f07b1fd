"""``ocalib synth``: render a synthetic multi-camera sequence to the native rig layout."""

from __future__ import annotations

import argparse
import os
import sys

# SynthConfig's defaults, which every preset keeps and a --config may set (a test keeps them equal): written out
# here so that building the parser imports no numpy
DEFAULTS = {"frames": 300, "seed": 0, "height": 128, "width": 416}


def add_parser(subparsers, name: str) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        name,
        help="render a synthetic rig sequence (street canyon, exact depth and poses)",
        description="Render a procedural street-canyon sequence seen by a camera rig: RGB images, depth PNGs "
        "(uint16, metres x 256) and KITTI poses for every camera, plus rig.yaml and times.txt.",
    )
    src = p.add_mutually_exclusive_group()
    src.add_argument(
        "--preset", help="built-in rig: front-rear, front-left, handheld, surround, stereo (default: front-rear)"
    )
    src.add_argument("--config", help="a YAML config file (see configs/synth/)")
    p.add_argument("--out", help="output folder (default: data/synth/<name of the preset or config>)")
    for option, text in [
        ("frames", "number of frames"),
        ("seed", "random seed of the world, the trajectory and the photometry"),
        ("height", "image height in pixels"),
        ("width", "image width in pixels"),
    ]:
        p.add_argument(f"--{option}", type=int, help=f"{text} (default: {DEFAULTS[option]}, or the --config file's)")
    p.add_argument(
        "--photometric",
        action="store_true",
        default=None,
        help="add per-camera gain, exposure jitter, vignetting and noise (default: off, or the --config file's)",
    )
    p.add_argument("--device", default="cpu", help="torch device: cpu, cuda (default: %(default)s)")
    p.add_argument(
        "--workers",
        type=int,
        default=min(4, os.cpu_count() or 1),
        help="CPU processes rendering frames (default: %(default)s: the CPUs, at most 4; the output does not depend on it)",
    )
    p.add_argument("--overwrite", action="store_true", help="replace a sequence already in --out (default: off)")
    return p


def run(args) -> int:
    from pathlib import Path

    from ocalib.synth import load_config, preset, render_sequence
    from ocalib.synth.sequence import camera_poses
    from ocalib.synth.trajectory import STRAIGHT_DEG, turned_deg

    given = dict(frames=args.frames, seed=args.seed, height=args.height, width=args.width, photometric=args.photometric)
    # the overrides go in before the checks, whose errors then name them as given here
    cfg = (
        load_config(args.config, **given)
        if args.config
        else preset(args.preset or "front-rear").with_overrides(**given)
    )
    out = Path(args.out) if args.out else Path("data") / "synth" / cfg.name
    turned = turned_deg(camera_poses(cfg)[0])
    if turned < STRAIGHT_DEG:
        print(
            f"ocalib synth: note: camera 0 turns at most {turned:.1f} deg in these {cfg.frames} frames (a straight "
            "route): the rotation between the cameras will not be observable from this motion; another --seed or "
            "more --frames gives a route with turns",
            file=sys.stderr,
        )
    render_sequence(cfg, out, device=args.device, overwrite=args.overwrite, workers=args.workers)
    print(f"wrote {cfg.frames} frames x {len(cfg.cameras)} cameras ({cfg.height}x{cfg.width}) to {out}")
    return 0
