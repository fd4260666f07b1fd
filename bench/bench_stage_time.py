"""Where ``ocalib calibrate``'s on-line path spends its time, stage by stage, at the resolution cameras record and at
the renders' 128x416: one run in this process under :mod:`cProfile`, the cumulative seconds of each stage's entry
point divided by the frames.

Stages: the image loader, the front end (its ego-motion per frame), the on-line head, and the on-line rig
estimator's parts (feature extraction, matching, resection with its information, triangulation, the window's
adjustment with its covariance). A stage's time includes what it calls; the profiler's own overhead inflates the
many small calls (the head's) more than the few large ones (SIFT, the adjustment).

    python bench/bench_stage_time.py --sequence data/kitti/dataset/sequences/01 \
        --metric-trajectory data/kitti/dataset/poses/01.txt [--frames 51] [--frontend auto] --label kitti-01-1241x376

Beside the profile, the cost of a frame in the stream without the profiler and without the start (imports, the
model, the first calls): ``calibrate`` run as a user runs it, in a fresh process, on the first ``frames`` and on the
first half of them (medians of ``--repeats``); the difference of their wall times over the difference of their frames,
and the same of their CPU times (every core's, the loader's worker process included): the work a frame costs, which
over the machine's cores bounds the wall time from below.

Writes ``bench/results/stage_time.json`` (one entry per ``--label``, kept across runs).
"""

from __future__ import annotations

import argparse
import contextlib
import cProfile
import io
import json
import pstats
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from common import shown_path, write_json

from ocalib.cli import main as ocalib_main

# stage -> its entry points (file suffix, function name), as the profiler names them
STAGES = {
    "images (loader)": [("data/stream.py", "__getitem__")],
    "front end": [("frontend/network.py", "forward"), ("frontend/opencv.py", "forward")],
    "on-line head": [("calib/drivers/online.py", "forward")],
    "rig estimator (all)": [("rigba/online.py", "update")],
    "  features (SIFT)": [("rigba/local_map.py", "features")],
    "  matching": [("rigba/features.py", "match_features")],
    "  resection + information": [("rigba/local_map.py", "resect")],
    "  triangulation": [("rigba/local_map.py", "triangulate")],
    "  window adjustment + covariance": [("rigba/window.py", "adjust_window")],
}


def stage_seconds(stats: pstats.Stats) -> dict[str, float]:
    """Cumulative seconds of each stage's entry point (0 where it never ran)."""
    out = dict.fromkeys(STAGES, 0.0)
    for (file, _, name), (_, _, _, cumulative, _) in stats.stats.items():
        for stage, entries in STAGES.items():
            if any(name == function and file.replace("\\", "/").endswith(suffix) for suffix, function in entries):
                out[stage] += cumulative
    return out


def streaming_ms(argv: list[str], frames: int, repeats: int) -> tuple[float, float, float]:
    """(ms a frame in the stream, CPU ms a frame in the stream, ms a frame of the whole command) of ``ocalib
    calibrate`` ``argv`` (its ``--max-frames`` appended), from fresh processes on ``frames // 2`` and ``frames``
    frames, alternated ``repeats`` times after one run that is not counted (it compiles and caches): the medians'
    difference."""
    walls: dict[int, list[float]] = {frames // 2: [], frames: []}
    cpus: dict[int, list[float]] = {frames // 2: [], frames: []}
    for n in [frames // 2] + [frames // 2, frames] * repeats:
        start, used = time.perf_counter(), _children_cpu()
        done = subprocess.run([sys.executable, "-m", "ocalib", *argv, "--max-frames", str(n)], capture_output=True)
        walls[n].append(time.perf_counter() - start)
        cpus[n].append(_children_cpu() - used)
        if done.returncode != 0:
            raise SystemExit(f"ocalib calibrate failed ({done.returncode}): {done.stderr.decode()[-300:]}")
    half, full = (float(np.median(walls[n][-repeats:])) for n in (frames // 2, frames))
    cpu_half, cpu_full = (float(np.median(cpus[n][-repeats:])) for n in (frames // 2, frames))
    per_frame = 1000 / (frames - frames // 2)
    return (full - half) * per_frame, (cpu_full - cpu_half) * per_frame, full / frames * 1000


def _children_cpu() -> float:
    """CPU seconds (user and system) of this process's finished children and their own."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sequence", required=True)
    p.add_argument("--metric-trajectory", required=True)
    p.add_argument("--frames", type=int, default=51)
    p.add_argument("--frontend", default="auto", help="calibrate's --frontend (default auto)")
    p.add_argument("--repeats", type=int, default=3, help="runs of each length for the cost in the stream")
    p.add_argument("--label", required=True, help="the name of this case in the JSON")
    p.add_argument("--out", default="bench/results/stage_time.json")
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        argv = ["calibrate", "--sequence", args.sequence, "--metric-trajectory", args.metric_trajectory,
                "--no-bundle-adjust", "--frontend", args.frontend, "--out", str(Path(tmp) / "out.json")]  # fmt: skip
        streaming, cpu, whole = streaming_ms(argv, args.frames, args.repeats)
        profile = cProfile.Profile()
        start = time.perf_counter()
        with contextlib.redirect_stdout(io.StringIO()):
            code = profile.runcall(ocalib_main, [*argv, "--max-frames", str(args.frames)])
        wall = time.perf_counter() - start
        result = json.loads((Path(tmp) / "out.json").read_text()) if code == 0 else {}
    if code != 0:
        raise SystemExit(f"ocalib calibrate failed ({code})")
    seconds = stage_seconds(pstats.Stats(profile))
    frames = result.get("settings", {}).get("frames", args.frames)
    print(f"{args.label}: {frames} frames, {wall:.1f} s under the profiler ({wall / frames * 1000:.0f} ms a frame)")
    print(f"  {'a frame in the stream (no profiler)':34} {streaming:8.1f} ms; the whole command {whole:.1f} ms a frame")
    print(f"  {'CPU time of a frame in the stream':34} {cpu:8.1f} ms (all cores)")
    for stage, s in seconds.items():
        print(f"  {stage:34} {s / frames * 1000:8.1f} ms a frame")
    path = Path(args.out)
    doc = json.loads(path.read_text()) if path.exists() else {"cases": {}}
    doc["cases"][args.label] = {
        "sequence": shown_path(args.sequence),
        "frames": frames,
        "wall_seconds_profiled": wall,
        "streaming_ms_per_frame": streaming,
        "streaming_cpu_ms_per_frame": cpu,
        "command_ms_per_frame": whole,
        "ms_per_frame": {stage: s / frames * 1000 for stage, s in seconds.items()},
        "frontend": result.get("settings", {}).get("frontend"),
    }
    write_json(path, doc)


if __name__ == "__main__":
    main()
