"""Cameras without a shared clock: a held-out rig rendered with camera 1 capturing late, calibrated with its clock
offset found (``--time-offset auto``) and with the offset ignored, against the synchronised render of the same seed.

Each late render is ``ocalib synth`` of the preset with camera 1's ``time_offset`` (its own ``times.txt`` says the
frames are synchronised); each run is ``ocalib calibrate``'s on-line pass (network front end) with the on-line rig
estimator, and the rig bundle adjustment, with camera 0's rendered poses as the metric trajectory
(:func:`bench_rigba.run`). Reported per run: the offset found and its error in frames, the on-line rig estimator's
and the bundle adjustment's rotation error (deg), translation direction error (deg; in the ground plane on cars)
and translation error over the baseline, and whether the adjustment was trusted.

    python bench/bench_time_offset.py [--sequences handheld-1001 front-left-1008] [--offsets 0.7 0.05 0.03]
"""

from __future__ import annotations

import argparse
import dataclasses
import re
import shutil
from pathlib import Path

import torch
from bench_calibnet_accuracy import ensure
from bench_rigba import run
from common import add_sequence_arguments, write_json

from ocalib.rigba.options import BundleOptions
from ocalib.synth import preset, render_sequence

KEYS = ("rotation_deg", "direction_deg", "translation_rel_baseline")


def render_late(root: Path, name: str, offset: float, frames: int) -> Path:
    """``name`` (PRESET-SEED, a held-out seed) at 128x416 with camera 1 ``offset`` seconds late, under ``root``."""
    path = root / f"{name}-late{offset:g}"
    if (path / "rig.yaml").exists():
        return path
    kind, seed = re.fullmatch(r"(.+)-(\d+)", name).groups()
    cfg = preset(kind).with_overrides(frames=frames, seed=int(seed), height=128, width=416)
    cameras = [cfg.cameras[0], dataclasses.replace(cfg.cameras[1], time_offset=offset), *cfg.cameras[2:]]
    partial = path.with_name(path.name + ".partial")
    shutil.rmtree(partial, ignore_errors=True)
    render_sequence(cfg.with_overrides(cameras=cameras), partial, workers=2)
    partial.rename(path)
    return path


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_sequence_arguments(p, ["handheld-1001", "front-left-1008"])
    p.add_argument("--offsets", type=float, nargs="+", default=[0.7, 0.05, 0.03], help="camera 1's lag, seconds")
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--out", default="bench/results/time_offset.json")
    args = p.parse_args()
    torch.set_num_threads(2)
    results = {}
    print(f"{'sequence':16} {'late s':>6} {'run':8} {'found s':>8} {'err fr':>6} {'estimator rot/dir/t':>20} "
          f"{'BA rot':>6} {'dir':>6} {'t/b':>6} trusted")  # fmt: skip
    for name in args.sequences:
        runs = [("synchronised", 0.0, ensure(Path(args.root), name, args.frames), None)]
        for offset in args.offsets:
            path = render_late(Path(args.root), name, offset, args.frames)
            runs += [("auto", offset, path, ["auto"]), ("ignored", offset, path, [0.0])]
        rows = results[name] = []
        for mode, offset, path, spec in runs:
            r = run(path, "network", args.frames, BundleOptions(), None, spec, online_rig=True)
            found = None if r["time_offsets"] is None else r["time_offsets"][1]
            row = {"mode": mode, "true_offset_s": offset, "found_offset_s": found}
            row["offset_error_frames"] = None if found is None else abs(found - offset) * 10.0
            row |= {key: r["bundle"][key] for key in KEYS} | {"trusted": r["trusted"], "head": r["head"]}
            row["rig_estimator"] = r["rig_estimator"]
            rows.append(row)
            err = "" if found is None else f"{found:8.4f} {row['offset_error_frames']:6.2f}"
            e = r["rig_estimator"]
            rig = "" if e is None else " / ".join(f"{e[key]:.2f}" for key in KEYS)
            print(f"{name:16} {offset:6.2f} {mode:8} {err:>15} {rig:>20} {row['rotation_deg']:6.2f} "
                  f"{row['direction_deg']:6.1f} {row['translation_rel_baseline']:6.2f} {row['trusted']}",
                  flush=True)  # fmt: skip
        write_json(args.out, {"frames": args.frames, "frame_rate": 10.0, "results": results})


if __name__ == "__main__":
    main()
