"""Rig calibration from images on held-out synthetic rigs: network vs OpenCV front end vs noisy true poses.

For each sequence (rendered by ``ocalib synth`` with a seed never used in training; rendered here when
missing), calibrates camera 1 against camera 0 with: the pose network (``--checkpoint``, default the
shipped one, with each ``--scale`` mode, and with ``--align`` with and without ``--rig-align``), OpenCV monocular VO, and the true poses with VO-like drift noise
of a few sizes (the reference of what the head makes of a front end of known quality). Reports the final
rotation error, translation direction error (in the ground plane on planar motion) and translation error
relative to the baseline after scaling camera 0's trajectory to metres. Prints a table, writes JSON.

    python bench/bench_calibnet_accuracy.py [--sequences DIR ...] [--frames 300] [--skip-opencv] [--skip-align]
"""

from __future__ import annotations

import argparse
import re
import shutil
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from common import add_sequence_arguments, write_json

from ocalib.calib.poses.pipeline import RigPoses, calibrate_rig
from ocalib.calibnet.run import calibrate_images
from ocalib.data.layout import open_sequence
from ocalib.eval.calibration_metrics import extrinsic_errors
from ocalib.frontend import FrontEndOptions
from ocalib.sim.trajectory import add_noise
from ocalib.synth import preset, render_sequence

# A quick default; the table of docs/results-calibrate.md has twelve: handheld-1001 ... 1009 (odd seeds), front-left-1002 ... 1014 (even).
DEFAULT = ["handheld-1001", "front-left-1002"]
NOISE = (0.002, 0.005)


def ensure(root: Path, name: str, frames: int) -> Path:
    """The sequence folder ``name`` (a path, or a name under ``root``); a missing one named PRESET-SEED (a held-out
    seed, >= 1000) is rendered there first, at 128x416, or PRESET-SEED-HxW at H x W (e.g. handheld-1003-256x832)."""
    path = Path(name) if Path(name).exists() or Path(name).parent != Path(".") else root / name
    if not (path / "rig.yaml").exists():
        match = re.fullmatch(r"(.+)-(\d+)(?:-(\d+)x(\d+))?", path.name)
        if not match or int(match[2]) < 1000:
            raise SystemExit(
                f"{name}: no sequence there, and its name is not PRESET-SEED[-HxW] with a held-out seed "
                "(>= 1000; lower seeds are training worlds), e.g. front-left-1008 or handheld-1003-256x832"
            )
        kind, seed = match[1], int(match[2])
        height, width = (int(match[3]), int(match[4])) if match[3] else (128, 416)
        partial = path.with_name(path.name + ".partial")  # an interrupted render leaves no rig.yaml at path
        shutil.rmtree(partial, ignore_errors=True)
        config = preset(kind).with_overrides(frames=frames, seed=seed, height=height, width=width)
        render_sequence(config, partial, workers=2)
        partial.rename(path)
    return path


def noisy_truth(path: Path, sigma: float, frames: int, seed: int = 0) -> list[dict]:
    """The head on the true poses with drift noise ``sigma`` (rad / metres per frame)."""
    seq = open_sequence(path)
    truth = np.stack([c.poses[:frames] for c in seq.cameras], 1)
    poses = torch.from_numpy(np.linalg.inv(truth[:1]) @ truth)
    noisy = add_noise(poses, sigma, torch.Generator().manual_seed(seed), model="drift").numpy()
    C = noisy.shape[1]
    rig = RigPoses(files=seq.names, poses=noisy, times=None, lines=np.ones((frames, C), int), time_offsets=[None] * C)
    run = calibrate_rig(rig)
    return extrinsic_errors(run.final, np.stack([c.T_cam0_cam for c in seq.cameras]), noisy, truth)


def row(errors: list[dict], seconds: float, frames: int) -> dict:
    e = errors[0]
    return {
        "rotation_deg": e["rotation_error_deg"],
        "direction_deg": e["translation_direction_error_deg"],
        "translation_rel_baseline": e.get("translation_error_rel_baseline"),
        "in_plane": e["compared_in_plane"],
        "fps": frames / seconds,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_sequence_arguments(p, DEFAULT)
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--checkpoint")
    p.add_argument("--skip-opencv", action="store_true")
    p.add_argument("--skip-align", action="store_true", help="leave out the network with photometric alignment")
    p.add_argument("--out", default="bench/results/calibnet_accuracy.json")
    args = p.parse_args()
    results = {}
    for name in args.sequences:
        path = ensure(Path(args.root), name, args.frames)
        res = results[path.name] = {}
        runs = [
            (f"network ({scale})", FrontEndOptions("network", scale=scale, align=False))
            for scale in ("head", "normalise")
        ]
        if not args.skip_align:
            runs.append(("network (normalise), aligned", FrontEndOptions("network", scale="normalise", align=True)))
            runs.append(
                (
                    "network (normalise), aligned, no rig",
                    FrontEndOptions("network", scale="normalise", align=True, rig_align=False),
                )
            )
        if not args.skip_opencv:
            runs.append(("opencv", FrontEndOptions("opencv")))
        for label, kw in runs:
            start = time.perf_counter()
            kw = replace(kw, checkpoint=args.checkpoint if kw.name == "network" else None)
            out = calibrate_images(path, frontend=kw, max_frames=args.frames, progress=False)
            res[label] = row(out.errors, time.perf_counter() - start, args.frames)
            flags = out.run.final
            res[label]["planar_flag"] = bool(flags.planar_motion[0, 0])
            res[label]["rotation_observable"] = bool(flags.rotation_observable[0, 0])
        for sigma in NOISE:
            start = time.perf_counter()
            res[f"true poses, drift {sigma}"] = row(
                noisy_truth(path, sigma, args.frames), time.perf_counter() - start, args.frames
            )
    print(f"{'sequence':18} {'front end':26} {'rot (deg)':>9} {'dir (deg)':>9} {'t/baseline':>10} {'fps':>7}")
    for name, res in results.items():
        for label, r in res.items():
            rel = r["translation_rel_baseline"]
            print(
                f"{name:18} {label:26} {r['rotation_deg']:9.3f} {r['direction_deg']:9.2f} "
                f"{'n/a' if rel is None else f'{rel:10.3f}':>10} {r['fps']:7.1f}"
                + ("  (in plane)" if r["in_plane"] else "")
            )
    write_json(args.out, {"frames": args.frames, "checkpoint": args.checkpoint or "default", "results": results})


if __name__ == "__main__":
    main()
