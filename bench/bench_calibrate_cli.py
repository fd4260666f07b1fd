"""Wall time of ``ocalib calibrate`` end to end (the on-line pass, no bundle adjustment), optionally beside another
checkout of ocalib in the same run.

Each case (front end x sequence) runs as its own process, ``--repeats`` times, the checkouts interleaved so that a
change in the machine's load hits them alike; medians are reported, with the frames per second of the whole command
(start-up, model loading and the image loader included). Prints a table and writes JSON.

    python bench/bench_calibrate_cli.py [--sequences front-left-1002] [--frames 100] [--repeats 3] [--compare DIR]

``--compare DIR``: another checkout (its ``ocalib`` package is put first on the path), e.g. a ``git worktree`` of
an earlier commit: the "no slower" check of a change.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench_calibnet_accuracy import ensure
from common import add_sequence_arguments, shown_path, write_json

from ocalib.frontend import FRONTENDS

HERE = Path(__file__).resolve().parents[1]


def run_once(tree: Path, sequence: Path, frontend: str, frames: int) -> float:
    """Seconds of one ``ocalib calibrate`` run with ``tree``'s package."""
    env = dict(os.environ, PYTHONPATH=str(tree), OMP_NUM_THREADS=os.environ.get("OMP_NUM_THREADS", "2"))
    with tempfile.TemporaryDirectory() as tmp:
        command = [sys.executable, "-m", "ocalib", "calibrate", "--sequence", str(sequence), "--frontend", frontend,
                   "--max-frames", str(frames), "--no-bundle-adjust", "--out", str(Path(tmp) / "r.json")]  # fmt: skip
        start = time.perf_counter()
        subprocess.run(command, env=env, cwd=tmp, check=True, capture_output=True)
        return time.perf_counter() - start


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_sequence_arguments(p, ["front-left-1002"])
    p.add_argument("--frontends", nargs="+", choices=FRONTENDS, default=list(FRONTENDS))
    p.add_argument("--frames", type=int, default=100)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--compare", metavar="DIR", help="another checkout of ocalib, timed beside this one")
    p.add_argument("--out", default="bench/results/calibrate_cli.json")
    args = p.parse_args()
    trees = {"this": HERE} | ({"compare": Path(args.compare).resolve()} if args.compare else {})
    times: dict[str, dict[str, list[float]]] = {}
    cases = [(ensure(Path(args.root), name, 300).resolve(), f) for name in args.sequences for f in args.frontends]
    for _ in range(args.repeats):
        for sequence, frontend in cases:
            for label, tree in trees.items():
                case = f"{sequence.name} {frontend}"
                times.setdefault(case, {}).setdefault(label, []).append(run_once(tree, sequence, frontend, args.frames))
    print(f"{'case':28} " + " ".join(f"{label + ' s':>10} {'frame/s':>8}" for label in trees) + "  ratio")
    results = {}
    for case, by_tree in times.items():
        medians = {label: statistics.median(t) for label, t in by_tree.items()}
        results[case] = {"median_s": medians, "all_s": by_tree}
        row = " ".join(f"{m:10.1f} {args.frames / m:8.1f}" for m in medians.values())
        ratio = f"  {medians['this'] / medians['compare']:.2f}" if "compare" in medians else ""
        print(f"{case:28} {row}{ratio}")
    trees_doc = {label: shown_path(tree) for label, tree in trees.items()}
    write_json(args.out, {"frames": args.frames, "repeats": args.repeats, "trees": trees_doc, "results": results})


if __name__ == "__main__":
    main()
