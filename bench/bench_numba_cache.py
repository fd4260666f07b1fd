"""Start-up cost of the head's compiled kernel (numba): cold (a fresh cache folder, so numba compiles) and warm (the
same folder again, so numba loads what it saved), in wall and CPU seconds, optionally beside another checkout of
ocalib in the same run.

Each start is its own process: it imports the head, runs one frame of one rig (the kernel's serial entry) and one
frame of 32 rigs (its parallel entry). ``NUMBA_CACHE_DIR`` points each cold start at a new empty folder and each warm
start at the folder its cold start filled. The checkouts are interleaved, each first in turn; medians are reported. Prints a table and
writes JSON.

    python bench/bench_numba_cache.py [--repeats 5] [--compare DIR]

``--compare DIR``: another checkout (its ``ocalib`` package is put first on the path), e.g. an earlier commit.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from common import shown_path, write_json

HERE = Path(__file__).resolve().parents[1]

# One start: seconds (wall and this process's CPU) of the imports, of the first frame of 1 rig and of 32 rigs, and
# numba's cache hits.
START = """
import json, time
clocks = [(time.perf_counter(), time.process_time())]
import torch
from ocalib.calib.drivers.online import OnlineCalibrator
clocks.append((time.perf_counter(), time.process_time()))
from ocalib.calib.drivers import kernel
clocks.append((time.perf_counter(), time.process_time()))
for rigs in (1, 32):
    head = OnlineCalibrator(2, batch_size=rigs)
    poses = torch.eye(4, dtype=torch.float64).expand(rigs, 2, 4, 4)
    clocks.append((time.perf_counter(), time.process_time()))
    head(poses)
    clocks.append((time.perf_counter(), time.process_time()))
wall = [clocks[1][0] - clocks[0][0], clocks[2][0] - clocks[1][0], clocks[4][0] - clocks[3][0], clocks[6][0] - clocks[5][0]]
cpu = [clocks[1][1] - clocks[0][1], clocks[2][1] - clocks[1][1], clocks[4][1] - clocks[3][1], clocks[6][1] - clocks[5][1]]
hits = sum(sum(f.stats.cache_hits.values()) for f in (kernel._rigs, kernel._parallel))
print(json.dumps({"wall": wall, "cpu": cpu, "cache_hits": hits}))
"""
COLUMNS = ("imports", "kernel import", "first frame, 1 rig", "first frame, 32 rigs")


def start(tree: Path, cache: Path) -> dict:
    """One start of the head with ``tree``'s package and numba's cache in ``cache``: the wall and CPU seconds of
    :data:`COLUMNS` and their totals, with numba's cache hits."""
    env = dict(os.environ, PYTHONPATH=str(tree), NUMBA_CACHE_DIR=str(cache))
    out = subprocess.run([sys.executable, "-c", START], env=env, cwd=cache, check=True, capture_output=True, text=True)
    doc = json.loads(out.stdout.splitlines()[-1])
    wall, cpu = dict(zip(COLUMNS, doc["wall"])), dict(zip(COLUMNS, doc["cpu"]))
    return {
        "wall": wall | {"total": sum(doc["wall"])},
        "cpu": cpu | {"total": sum(doc["cpu"])},
        "cache_hits": doc["cache_hits"],
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--compare", metavar="DIR", help="another checkout of ocalib, timed beside this one")
    p.add_argument("--out", default="bench/results/numba_cache.json")
    args = p.parse_args()
    trees = {"this": HERE} | ({"compare": Path(args.compare).resolve()} if args.compare else {})
    runs: dict[str, dict[str, list[dict]]] = {label: {"cold": [], "warm": []} for label in trees}
    for repeat in range(args.repeats):
        for label, tree in list(trees.items())[:: 1 if repeat % 2 == 0 else -1]:  # each checkout first in turn
            with tempfile.TemporaryDirectory() as cache:
                runs[label]["cold"].append(start(tree, Path(cache)))
                runs[label]["warm"].append(start(tree, Path(cache)))
    rows = {}
    print(f"{'checkout':10} {'start':5} {'clock':5} " + " ".join(f"{c:>21}" for c in (*COLUMNS, "total")))
    for label, kinds in runs.items():
        for kind, starts in kinds.items():
            row = {clock: {c: statistics.median(s[clock][c] for s in starts) for c in (*COLUMNS, "total")}
                   for clock in ("wall", "cpu")}  # fmt: skip
            row["cache_hits"] = [s["cache_hits"] for s in starts]
            rows[f"{label} {kind}"] = row
            for clock in ("wall", "cpu"):
                cells = " ".join(f"{row[clock][c]:>20.2f}s" for c in (*COLUMNS, "total"))
                print(f"{label:10} {kind:5} {clock:5} {cells}")
    doc = {"repeats": args.repeats, "trees": {k: shown_path(v) for k, v in trees.items()}, "unit": "s, median",
           "rows": rows}  # fmt: skip
    write_json(args.out, doc)


if __name__ == "__main__":
    main()
