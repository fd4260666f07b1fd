"""Tensor operations the PyTorch head dispatches per frame, by the ocalib module that calls them.

At a few rigs the PyTorch head (``backend="torch"``) costs what it dispatches, a few microseconds an operation,
whatever the arithmetic. The count does not depend on the machine's load, so it says, where timings disagree by
their noise, what a change to the head added or removed and in which stage's module.

``--against DIR`` counts another checkout of ocalib (e.g. ``git worktree add /tmp/before <commit>``) beside this
one, each in a fresh process (``PYTHONPATH``). Prints a table and writes ``bench/results/head_ops.json``.

    python bench/bench_head_ops.py [--against DIR] [--rigs 64]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from collections import Counter
from pathlib import Path

import torch
from bench_online import rig_sequence
from common import shown_path, write_json
from torch.utils._python_dispatch import TorchDispatchMode

from ocalib.calib.drivers.online import OnlineCalibrator

OUT = Path(__file__).parent / "results" / "head_ops.json"
WARMUP, FRAMES = 20, 10  # frames before counting (the gaps' history fills), frames counted


def caller_module() -> str:
    """The innermost ocalib module on the stack (``calib/stages/refine.py``), or ``other``."""
    frame = sys._getframe(2)
    while frame is not None:
        name = frame.f_code.co_filename
        if f"{os.sep}ocalib{os.sep}" in name:
            return name.rsplit(f"{os.sep}ocalib{os.sep}", 1)[1]
        frame = frame.f_back
    return "other"


class CountOperations(TorchDispatchMode):
    """Counts every dispatched tensor operation by :func:`caller_module`."""

    def __init__(self):
        super().__init__()
        self.counts: Counter[str] = Counter()

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        self.counts[caller_module()] += 1
        return func(*args, **(kwargs or {}))


def count(rigs: int, refine: bool) -> dict[str, float]:
    """Operations per frame of the PyTorch head on ``rigs`` noisy LDS rigs, by module."""
    poses = rig_sequence(WARMUP + FRAMES, rigs)
    head = OnlineCalibrator(2, batch_size=rigs, backend="torch", refine=refine)
    with torch.inference_mode():
        for t in range(WARMUP):
            head(poses[t])
        with CountOperations() as mode:
            for t in range(WARMUP, WARMUP + FRAMES):
                head(poses[t])
    return {name: n / FRAMES for name, n in mode.counts.items()}


def counts_of(tree: str, rigs: int) -> dict[str, dict[str, float]]:
    """:func:`count` of the checkout ``tree``, refined and closed form, in a fresh process."""
    env = dict(os.environ, PYTHONPATH=tree)
    out = subprocess.run([sys.executable, __file__, "--case", str(rigs)], env=env, capture_output=True, text=True)
    if out.returncode:
        raise RuntimeError(f"{tree}: {out.stderr[-2000:]}")
    return json.loads(out.stdout.splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--against", metavar="DIR", help="count the head of the ocalib checkout in DIR beside this one")
    parser.add_argument("--rigs", type=int, default=64, help="rigs in the batch (default 64)")
    parser.add_argument("--case", type=int, help=argparse.SUPPRESS)  # counts of this process's ocalib, printed
    args = parser.parse_args()
    if args.rigs < 1:
        parser.error(f"--rigs {args.rigs}: need at least one rig")
    if args.case is not None:
        print(json.dumps({label: count(args.case, refine) for label, refine in (("refined", True), ("closed", False))}))
        return
    trees = {"this": str(Path(__file__).resolve().parents[1])}
    if args.against:
        if not (Path(args.against) / "ocalib").is_dir():
            parser.error(f"--against {args.against}: no ocalib checkout there (no ocalib/ folder)")
        trees = {"other": str(Path(args.against).resolve()), **trees}
    counts = {name: counts_of(tree, args.rigs) for name, tree in trees.items()}
    print(
        f"tensor operations per frame, PyTorch head, {args.rigs} rigs: "
        + ", ".join(f"{n} = {t}" for n, t in trees.items())
    )
    print(f"{'module (refined)':<32}" + "".join(f"{n:>10}" for n in trees))
    modules = sorted(
        {m for c in counts.values() for m in c["refined"]}, key=lambda m: -counts["this"]["refined"].get(m, 0)
    )
    for label in ("refined", "closed"):
        print(f"{'total, ' + label:<32}" + "".join(f"{sum(c[label].values()):>10.0f}" for c in counts.values()))
    for m in modules:
        print(f"  {m:<30}" + "".join(f"{c['refined'].get(m, 0):>10.0f}" for c in counts.values()))
    trees_doc = {name: shown_path(tree) for name, tree in trees.items()}
    write_json(OUT, {"rigs": args.rigs, "trees": trees_doc, "operations_per_frame": counts})


if __name__ == "__main__":
    main()
