"""The on-line head's change test (``calibrate-poses``') on the motions ``ocalib calibrate``'s own front end makes,
on the rendered test split of ``bench_calibrate_split.py``: knocks found and false alarms.

Per rig, ``ocalib calibrate --sequence DIR --no-bundle-adjust --trajectories ...`` (the front end chosen as by
default) writes every camera's trajectory once (kept under ``ROOT/runs/frontend/``); ``calibrate-poses``' path
(:func:`ocalib.calib.poses.pipeline.calibrate_rig`, its change test as it ships) then runs on them. A change named
on a steady rig is a false alarm; a knocked rig's (camera 1 turned by 2 deg at frame 150, cars also moved 5 cm)
counts when the knocked camera's change is named from frame 146 on and noticed within 30 frames. Cameras whose
head never settled are counted as untested (the test does not run on them).

    python bench/bench_head_change_split.py --split test [--root data/eval] [--presets front-left handheld] [--rendered]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
from bench_calibrate_split import DETECT_WITHIN, FRAMES, rigs, wilson
from common import write_json

from ocalib.calib.poses.pipeline import RigPoses, calibrate_rig
from ocalib.data.layout import open_sequence
from ocalib.io.poses import read_poses


def trajectories(root: Path, rig: str) -> tuple[list[str], np.ndarray]:
    """The camera names and their front-end trajectories (T, C, 4, 4) of ``calibrate`` on ``root / rig``."""
    folder = root / "runs" / "frontend" / rig
    names = open_sequence(root / rig).names
    if not all((folder / f"{n}.txt").exists() for n in names):
        command = [sys.executable, "-m", "ocalib", "calibrate", "--sequence", str(root / rig), "--no-bundle-adjust",
                   "--trajectories", str(folder), "--out", str(folder / "calibrate.json")]  # fmt: skip
        done = subprocess.run(command, capture_output=True, text=True)
        if done.returncode != 0:
            raise SystemExit(f"{rig}: ocalib calibrate failed ({done.returncode}): {done.stderr.strip()[-500:]}")
    return names, np.stack([read_poses(folder / f"{n}.txt").poses for n in names], 1)


def head_changes(names: list[str], poses: np.ndarray) -> tuple[list[dict], int]:
    """The changes ``calibrate-poses``' path declares on ``poses`` (T, C, 4, 4), and the cameras it could not test."""
    T, C = poses.shape[:2]
    lines = np.tile(np.arange(1, T + 1)[:, None], (1, C))
    run = calibrate_rig(RigPoses(names, poses, None, lines, [None] * C, [None] * C))
    untested = sum("could not be tested" in w for w in run.warnings)
    return [{k: c[k] for k in ("camera", "frame", "detected", "rotation_change_deg", "translation_change")}
            for c in run.changes], untested  # fmt: skip


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--split", default="test")
    p.add_argument("--root", default="data/eval")
    p.add_argument("--presets", nargs="+", default=["front-left", "handheld", "surround"])
    p.add_argument("--rendered", action="store_true", help="only the rigs already rendered under --root")
    p.add_argument("--out", default="bench/results/head_change_split.json")
    args = p.parse_args()
    root, rows = Path(args.root), []
    for name, knocked in rigs(args.split, args.presets):
        rig = name + "-knocked" * knocked
        if args.rendered and not (root / rig).is_dir():
            continue
        names, poses = trajectories(root, rig)
        changes, untested = head_changes(names, poses)
        rows.append({"rig": rig, "knocked": knocked, "frames": len(poses), "cameras": len(names) - 1,
                     "untested": untested, "changes": changes})  # fmt: skip
        print(
            f"{rig:24} untested {untested}  "
            + ", ".join(
                f"{c['camera']} {c['frame']}/{c['detected']} {c['rotation_change_deg']:.2f} deg" for c in changes
            ),
            flush=True,
        )
    summary = {}
    for preset in args.presets:
        mine = [r for r in rows if r["rig"].startswith(preset + "-")]
        steady, knocked = [r for r in mine if not r["knocked"]], [r for r in mine if r["knocked"]]
        s = {"steady_rigs": len(steady), "steady_frames": sum(r["frames"] for r in steady),
             "false_alarms": sum(len(r["changes"]) for r in steady),
             "rigs_with_false_alarms": sum(bool(r["changes"]) for r in steady),
             "untested_cameras": sum(r["untested"] for r in steady), "cameras": sum(r["cameras"] for r in steady)}  # fmt: skip
        if knocked:
            names = {r["rig"]: open_sequence(root / r["rig"]).names[1] for r in knocked}
            hit = sum(any(c["camera"] == names[r["rig"]] and c["frame"] >= FRAMES // 2 - 4
                          and c["detected"] - FRAMES // 2 <= DETECT_WITHIN for c in r["changes"]) for r in knocked)  # fmt: skip
            s["knocks"] = {"rigs": len(knocked), "detected_within": hit, "interval": wilson(hit, len(knocked)),
                           "untested": sum(r["untested"] > 0 for r in knocked)}  # fmt: skip
        summary[preset] = s
        print(preset, json.dumps(s))
    write_json(args.out, {"split": args.split, "frames": FRAMES, "summary": summary, "rows": rows})


if __name__ == "__main__":
    main()
