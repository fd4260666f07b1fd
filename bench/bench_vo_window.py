"""The OpenCV VO's sliding-window bundle adjustment alone (``ocalib.frontend.window.bundle_adjust``), on the windows
of a real sequence, optionally beside another checkout of ocalib in the same run.

First the windows are recorded: ``ocalib calibrate --frontend opencv --no-bundle-adjust`` on the first ``--frames``
frames, every call of the adjustment's arguments and results kept. Then each checkout, in a fresh process (its
``ocalib`` package first on the path), adjusts every recorded window once uncounted (numba loads or compiles its
kernel) and then ``--repeats`` times, timed; the checkouts alternate, each first in turn, and the medians are
reported. Each process also checks its results against the recorded ones bit for bit.

    python bench/bench_vo_window.py --sequence data/kitti/dataset/sequences/01 \
        --metric-trajectory data/kitti/dataset/poses/01.txt [--frames 51] [--compare DIR] [--label NAME]

Writes ``bench/results/vo_window.json`` (one entry per ``--label``, kept across runs).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import pickle
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from common import shown_path, write_json

HERE = Path(__file__).resolve().parents[1]

# One process: every recorded window adjusted once uncounted, then `repeats` times; the seconds of each pass and
# the number of outputs that differ from the recorded ones in any bit.
TIME = """
import pickle, sys, time, json
import numpy as np
import ocalib
from ocalib.frontend.window import bundle_adjust
windows = pickle.load(open(sys.argv[1], "rb"))
def adjust_all():
    return [bundle_adjust(*args, **kw) for args, kw, _ in windows]
first = adjust_all()
differ = sum(int(np.any(np.asarray(x).view(np.int64) != np.asarray(y).view(np.int64)))
             for (_, _, out), new in zip(windows, first) for x, y in zip(out, new))
seconds = []
for _ in range(int(sys.argv[2])):
    start = time.perf_counter()
    adjust_all()
    seconds.append(time.perf_counter() - start)
print(json.dumps({"seconds": seconds, "differ": differ, "package": ocalib.__file__}))
"""


def record(argv: list[str], path: Path) -> int:
    """Run ``ocalib calibrate`` ``argv`` in this process, pickling every window adjustment's ``(args, kwargs,
    results)`` to ``path``; the number of windows."""
    import ocalib.frontend.opencv_vo as vo
    from ocalib.cli import main as ocalib_main

    adjust, windows = vo.bundle_adjust, []

    def recording(*args, **kw):
        out = adjust(*args, **kw)
        windows.append((args, kw, out))
        return out

    vo.bundle_adjust = recording
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            code = ocalib_main(argv)
    finally:
        vo.bundle_adjust = adjust
    if code != 0:
        raise SystemExit(f"ocalib calibrate failed ({code})")
    path.write_bytes(pickle.dumps(windows))
    return len(windows)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sequence", required=True)
    p.add_argument("--metric-trajectory", required=True)
    p.add_argument("--frames", type=int, default=51)
    p.add_argument("--repeats", type=int, default=5, help="timed passes over the windows in each process")
    p.add_argument("--rounds", type=int, default=3, help="processes of each checkout, alternated")
    p.add_argument("--compare", metavar="DIR", help="another checkout of ocalib, timed beside this one")
    p.add_argument("--label", default="kitti-01-1241x376")
    p.add_argument("--out", default="bench/results/vo_window.json")
    args = p.parse_args()
    trees = {"this": HERE} | ({"compare": Path(args.compare).resolve()} if args.compare else {})
    with tempfile.TemporaryDirectory() as tmp:
        windows = Path(tmp) / "windows.pkl"
        argv = ["calibrate", "--sequence", args.sequence, "--metric-trajectory", args.metric_trajectory,
                "--no-bundle-adjust", "--frontend", "opencv", "--max-frames", str(args.frames),
                "--out", str(Path(tmp) / "out.json")]  # fmt: skip
        count = record(argv, windows)
        runs: dict[str, list[dict]] = {label: [] for label in trees}
        for repeat in range(args.rounds):
            for label, tree in list(trees.items())[:: 1 if repeat % 2 == 0 else -1]:  # each checkout first in turn
                env = dict(os.environ, PYTHONPATH=str(tree))
                out = subprocess.run([sys.executable, "-c", TIME, str(windows), str(args.repeats)], env=env, cwd=tmp,
                                     check=True, capture_output=True, text=True)  # fmt: skip
                runs[label].append(json.loads(out.stdout.splitlines()[-1]))
    rows = {}
    for label, done in runs.items():
        seconds = statistics.median(s for run in done for s in run["seconds"])
        rows[label] = {"tree": shown_path(trees[label]), "seconds_all_windows": seconds,
                       "ms_per_window": seconds / count * 1000, "ms_per_frame": seconds / args.frames * 1000,
                       "outputs_differing_from_recorded": sum(run["differ"] for run in done),
                       "package": shown_path(Path(done[0]["package"]).parents[1])}  # fmt: skip
        print(f"{label:8} {seconds:7.3f} s for {count} windows ({seconds / args.frames * 1000:.1f} ms a frame), "
              f"{rows[label]['outputs_differing_from_recorded']} outputs differing from the recorded ones")  # fmt: skip
    ratio = rows["compare"]["seconds_all_windows"] / rows["this"]["seconds_all_windows"] if "compare" in rows else None
    if ratio is not None:
        print(f"compare / this: {ratio:.2f}x")
    path = Path(args.out)
    doc = json.loads(path.read_text()) if path.exists() else {"cases": {}}
    doc.pop("machine", None)
    doc["cases"][args.label] = {"sequence": args.sequence, "frames": args.frames, "windows": count,
                                "repeats": args.repeats, "rounds": args.rounds, "unit": "s, median",
                                "recorded_with": "this", "rows": rows, "compare_over_this": ratio}  # fmt: skip
    write_json(path, doc)


if __name__ == "__main__":
    main()
