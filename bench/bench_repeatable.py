"""Run-to-run spread of the rig bundle adjustment: the same sequence adjusted several times with COLMAP on every
core, with its mapper alone on one thread, and all on one thread (as ``ocalib calibrate`` runs it by default), side
by side in one run.

For each sequence, ``ocalib calibrate``'s on-line pass runs once (it gives the same result every time), then the
bundle adjustment ``--runs`` times in each mode, each from the same on-line result, with the sequence's camera-0
poses as the metric trajectory. Reported per mode: the median seconds of the stage (and its ratio to the first
mode's), the spread (largest minus smallest) of camera 1's rotation error (deg), translation direction error (deg;
in the ground plane on cars) and translation error over the baseline, the largest change of the extrinsic between
runs (rotation deg; translation mm in 3-D, a car's unobservable height included), the number of distinct results
(bit for bit), and the adjustment's own 1-sigma (rotation deg, translation mm) beside them. Prints a table, writes
JSON.

    python bench/bench_repeatable.py [--sequences front-left-1008 handheld-1001] [--runs 4] [--modes ...]
"""

from __future__ import annotations

import argparse
import itertools
import time
from pathlib import Path

import numpy as np
import torch
from bench_calibnet_accuracy import ensure
from bench_rigba import errors_row
from common import add_sequence_arguments, write_json

from ocalib.calibnet.bundle import refine_calibration
from ocalib.calibnet.run import calibrate_images
from ocalib.frontend import FrontEndOptions
from ocalib.geometry.se3 import rotation_angle_deg
from ocalib.rigba.options import BundleOptions, FeatureOptions, MapperOptions

KEYS = ("rotation_deg", "direction_deg", "translation_rel_baseline")
# (feature extraction and matching, mapper) threads; -1: every core
MODES = {"all threads": (-1, -1), "mapper on one thread": (-1, 1), "one thread (--repeatable)": (1, 1)}


def adjust(result, metric, threads: tuple[int, int]) -> dict:
    """One bundle adjustment of ``result``'s frames with ``threads`` (features and matching, mapper) -> camera 1's
    errors, extrinsic (4, 4), 1-sigma and seconds."""
    options = BundleOptions(FeatureOptions(threads=threads[0]), MapperOptions(threads=threads[1]))
    start = time.perf_counter()
    refine_calibration(result, metric, options, progress=False)
    seconds = time.perf_counter() - start
    b, u = result.bundle, result.bundle.uncertainty[1]
    return {
        "errors": errors_row(result.bundle_errors[0]),
        "extrinsic": b.extrinsics[1].tolist(),
        "trusted": bool(b.trusted[1]),
        "rotation_std_deg": None if u is None else float(np.degrees(u.rotation_std).max()),
        "translation_std_mm": None if u is None else float(1000 * np.nanmax(np.where(np.isinf(u.translation_std),
                                                                                      np.nan, u.translation_std))),
        "seconds": seconds,
    }  # fmt: skip


def spread(runs: list[dict]) -> dict:
    """The spread of the runs' errors, the largest change between two runs' extrinsics, the distinct results."""
    E = [np.asarray(r["extrinsic"]) for r in runs]
    pairs = list(itertools.combinations(E, 2))
    return {
        **{f"{k}_spread": float(np.ptp([r["errors"][k] for r in runs])) for k in KEYS},
        "rotation_change_deg_max": max((float(rotation_angle_deg(a[:3, :3].T @ b[:3, :3])) for a, b in pairs), default=0),
        "translation_change_mm_max": max((1000 * float(np.linalg.norm(a[:3, 3] - b[:3, 3])) for a, b in pairs),
                                         default=0),
        "distinct_results": len({e.tobytes() for e in E}),
        "seconds_median": float(np.median([r["seconds"] for r in runs])),
        "rotation_std_deg": float(np.median([r["rotation_std_deg"] or np.nan for r in runs])),
        "translation_std_mm": float(np.median([r["translation_std_mm"] or np.nan for r in runs])),
    }  # fmt: skip


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_sequence_arguments(p, ["front-left-1008", "handheld-1001"])
    p.add_argument("--runs", type=int, default=4)
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--frontend", default="network")
    p.add_argument("--modes", nargs="+", choices=MODES, default=list(MODES))
    p.add_argument("--out", default="bench/results/repeatable.json")
    args = p.parse_args()
    torch.set_num_threads(2)
    results = {}
    print(f"{'sequence':16} {'mode':36} {'s':>6} {'rot/dir/t spread':>22} {'max change deg/mm':>18} {'distinct':>8} "
          f"{'1-sigma deg/mm':>15}")  # fmt: skip
    for name in args.sequences:
        path = ensure(Path(args.root), name, args.frames)
        online = calibrate_images(path, frontend=FrontEndOptions(args.frontend), max_frames=args.frames,
                                  progress=False)  # fmt: skip
        metric = online.sequence.cameras[0].poses
        r = results[path.name] = {}
        for mode in args.modes:
            threads = MODES[mode]
            runs = [adjust(online, metric, threads) for _ in range(args.runs)]
            s = spread(runs)
            first = next(iter(r.values()), None)  # the first mode run: the reference for the time
            s["seconds_ratio_to_first_mode"] = (
                s["seconds_median"] / (first or {"summary": s})["summary"]["seconds_median"]
            )
            r[mode] = {"threads": threads, "runs": runs, "summary": s}
            print(f"{path.name:16} {mode:36} {s['seconds_median']:6.1f} "
                  f"{s['rotation_deg_spread']:6.3f} {s['direction_deg_spread']:6.2f} "
                  f"{s['translation_rel_baseline_spread']:6.3f}   {s['rotation_change_deg_max']:7.3f} "
                  f"{s['translation_change_mm_max']:8.1f} {s['distinct_results']:8d} "
                  f"{s['rotation_std_deg']:7.3f} {s['translation_std_mm']:7.1f}", flush=True)  # fmt: skip
            write_json(args.out, {"runs": args.runs, "frames": args.frames, "frontend": args.frontend,
                                  "results": results})  # fmt: skip


if __name__ == "__main__":
    main()
