"""The OpenCV VO's tracker settings side by side (``ocalib.frontend.tracker.KLTTracker``): per camera of each sequence,
the median error of its frame-to-frame rotation and translation direction against the truth, and its time a step.

    python bench/bench_vo_tracker.py [--sequences data/eval/front-left-6001 ... data/kitti/dataset/sequences/01]
                                     [--frames 150] [--settings default win_size=15 max_features=400,win_size=15]

Each camera's frames are decoded to 8-bit grey first (the time is the odometry's alone, one thread; the run and its
errors as ``bench_opencv_vo.py`` counts them); the settings run one after another on the same frames. Sequences need
their true poses (renders; KITTI odometry with its poses file). Writes ``bench/results/vo_tracker.json``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from bench_opencv_vo import run_vo
from common import shown_path, write_json

from ocalib.data.layout import open_sequence
from ocalib.eval.pose_metrics import step_errors

DEFAULT_SEQUENCES = [
    *(f"data/eval/{preset}-{seed}" for preset in ("front-left", "handheld") for seed in (6001, 6002)),
    "data/eval/surround-6001",
    "data/kitti/dataset/sequences/01",
    "data/kitti/dataset/sequences/06",
]


def parse_setting(text: str) -> dict:
    """``default`` -> {}; ``win_size=15,max_features=400`` -> {"win_size": 15, "max_features": 400}."""
    if text == "default":
        return {}
    return {key: int(value) for key, value in (item.split("=") for item in text.split(","))}


def run(camera, frames: list[np.ndarray], setting: dict) -> dict:
    """One camera's odometry over ``frames`` with the tracker ``setting`` -> ms a step, median errors (deg) of its
    motions that are not flagged degenerate (as :mod:`bench_opencv_vo` counts them)."""
    poses, degenerate, fps = run_vo(camera, frames, **setting)
    errors = step_errors(poses, np.asarray(camera.poses[: len(frames)]), ~degenerate)
    return {"ms_per_step": 1000 / fps, "rotation_deg": float(np.median(errors["rotation_deg"])),
            "direction_deg": float(np.nanmedian(errors["direction_deg"]))}  # fmt: skip


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sequences", nargs="+", default=DEFAULT_SEQUENCES)
    p.add_argument("--frames", type=int, default=150)
    p.add_argument("--settings", nargs="+", default=["default", "win_size=15", "max_features=400,win_size=15"])
    p.add_argument("--out", default="bench/results/vo_tracker.json")
    args = p.parse_args()
    rows = []
    for path in args.sequences:
        if not Path(path).exists():
            print(f"{path}: missing, skipped")
            continue
        sequence = open_sequence(path)
        n = min(args.frames, len(sequence))
        for k, cam in enumerate(sequence.cameras):
            frames = [cam.read_grey(t) for t in range(n)]
            for setting in args.settings:
                row = {"sequence": shown_path(path), "camera": k, "setting": setting}
                row |= run(cam, frames, parse_setting(setting))
                rows.append(row)
                print(f"{Path(path).name} cam{k} {setting:32} {row['ms_per_step']:6.1f} ms  rotation "
                      f"{row['rotation_deg']:.4f} deg  direction {row['direction_deg']:.3f} deg", flush=True)  # fmt: skip
    summary = {}
    base = {(r["sequence"], r["camera"]): r for r in rows if r["setting"] == args.settings[0]}
    for setting in args.settings[1:]:
        pairs = [(base[(r["sequence"], r["camera"])], r) for r in rows if r["setting"] == setting]
        summary[setting] = {
            "cameras": len(pairs),
            "rotation_better": sum(r["rotation_deg"] < b["rotation_deg"] for b, r in pairs),
            "direction_better": sum(r["direction_deg"] < b["direction_deg"] for b, r in pairs),
            "rotation_ratio_median": float(np.median([r["rotation_deg"] / b["rotation_deg"] for b, r in pairs])),
            "direction_ratio_median": float(np.median([r["direction_deg"] / b["direction_deg"] for b, r in pairs])),
            "time_ratio_median": float(np.median([r["ms_per_step"] / b["ms_per_step"] for b, r in pairs])),
        }
        s = summary[setting]
        print(f"{setting} against {args.settings[0]}, {s['cameras']} cameras: rotation better on "
              f"{s['rotation_better']} (median ratio {s['rotation_ratio_median']:.2f}), direction better on "
              f"{s['direction_better']} ({s['direction_ratio_median']:.2f}), time {s['time_ratio_median']:.2f}x")  # fmt: skip
    write_json(args.out, {"frames": args.frames, "settings": args.settings, "rows": rows, "summary": summary})


if __name__ == "__main__":
    main()
