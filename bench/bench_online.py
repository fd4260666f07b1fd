"""Per-frame cost of the on-line calibration head against re-solving from scratch every frame.

Measures, in one run on this machine:
* the head's per-frame update (``OnlineCalibrator.forward``, reading the estimate) for 1, 64 and 4096 rigs
  batched, with the joint refinement (the default) and without (``refine=False``, the closed form), in its two
  backends side by side: the compiled CPU kernel (``backend="auto"``, :mod:`ocalib.calib.drivers.kernel`; on all of
  numba's threads, and for 4096 rigs also on one) and PyTorch (``backend="torch"``, one intra-op thread: on this shared
  2-core machine two were 10x slower for 4096 rigs);
* the whole-sequence path (``calibrate_sequence``: the same estimates for a recorded sequence), per frame;
* re-solving the batch problem (``batch_calibrate``) on all N frames so far, which is what a non-recursive method
  pays per frame, and one ``cv2.calibrateHandEye`` call on N poses (OpenCV builds motions from all pose pairs),
  both at N = 128 and 1000.

Prints a table and writes ``bench/results/online.json``. Medians over repeats; the streaming cases run
interleaved, ``--repeats`` times, so that a change in the machine's load hits all of them alike. The kernel's
compilation (or loading from numba's cache) happens before the timed frames.

``--against DIR`` times the head's cases (not the batch and OpenCV ones) of another checkout of ocalib, e.g. a
``git worktree add /tmp/before <commit>``, beside this one's: each case in a fresh process for each checkout
(``PYTHONPATH``), the two alternating, ``--repeats`` times; prints the medians side by side and writes
``bench/results/online_against.json``.

    python bench/bench_online.py [--quick] [--against DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numba
import numpy as np
import torch
from common import shown_path, write_json

from ocalib.calib.drivers.batch import batch_calibrate
from ocalib.calib.drivers.online import OnlineCalibrator
from ocalib.calib.drivers.sequence import calibrate_sequence
from ocalib.sim.trajectory import add_noise, lds_trajectory, random_rig, rig_trajectories

OUT = Path(__file__).parent / "results" / "online.json"
OUT_AGAINST = Path(__file__).parent / "results" / "online_against.json"
THREADS = numba.get_num_threads()  # the kernel's default: one per core
FRAMES = {
    False: {1: 300, 64: 200, 4096: 16},
    True: {1: 40, 64: 30, 4096: 4},
}  # timed frames (after 20 warm-up), --quick
SEQUENCE_FRAMES = {False: {1: 2000, 4096: 32}, True: {1: 200, 4096: 8}}


def rig_sequence(frames: int, rigs: int, seed: int = 0) -> torch.Tensor:
    """(frames, rigs, 2, 4, 4) noisy LDS trajectories of random rigs."""
    g = torch.Generator().manual_seed(seed)
    seqs = [
        add_noise(rig_trajectories(lds_trajectory(frames, g), random_rig(g)[None]), 0.01, g)
        for _ in range(min(rigs, 8))
    ]
    return torch.stack([seqs[i % len(seqs)] for i in range(rigs)], 1)


def time_stream(poses: torch.Tensor, warmup: int = 20, threads: int = THREADS, **options) -> list[float]:
    """Seconds per frame of the head (forward + reading the estimate) on poses (T, B, 2, 4, 4); ``threads``: the
    kernel's (numba's) threads."""
    cal = OnlineCalibrator(2, batch_size=poses.shape[1], **options)
    numba.set_num_threads(threads)
    times = []
    with torch.inference_mode():
        for t in range(len(poses)):
            start = time.perf_counter()
            cal(poses[t]).rotation.sum()
            if t >= warmup:
                times.append(time.perf_counter() - start)
    numba.set_num_threads(THREADS)
    return times


def time_sequence(poses: torch.Tensor) -> float:
    """Seconds per frame of the whole-sequence path on poses (T, B, 2, 4, 4)."""
    with torch.inference_mode():
        start = time.perf_counter()
        calibrate_sequence(poses)
        return (time.perf_counter() - start) / len(poses)


def time_batch_resolve(n: int, repeats: int) -> list[float]:
    poses = rig_sequence(n, 1)[:, 0]
    times = []
    with torch.inference_mode():
        for _ in range(repeats):
            start = time.perf_counter()
            batch_calibrate(poses, "multi")
            times.append(time.perf_counter() - start)
    return times


def time_opencv(n: int, repeats: int, method: int) -> list[float]:
    poses = rig_sequence(n, 1)[:, 0].numpy()
    # AX = XB with A = camera-0 poses ("gripper to base") and B = inverse camera-1 poses ("target to camera").
    R_g, t_g = poses[:, 0, :3, :3], poses[:, 0, :3, 3]
    inv1 = np.linalg.inv(poses[:, 1])
    R_t, t_t = inv1[:, :3, :3], inv1[:, :3, 3]
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        cv2.calibrateHandEye(list(R_g), list(t_g), list(R_t), list(t_t), method=method)
        times.append(time.perf_counter() - start)
    return times


def time_case(kind: str, rigs: int, refine: bool, threads: int, quick: bool) -> list[float]:
    """Seconds per frame of one case: ``kind`` a backend (``"auto"``, ``"torch"``) or ``"sequence"``."""
    with torch.inference_mode():  # compile the kernel (or load it from numba's cache) before timing
        OnlineCalibrator(2, batch_size=64)(rig_sequence(1, 64)[0])
    if kind == "sequence":
        return [time_sequence(rig_sequence(SEQUENCE_FRAMES[quick][rigs], rigs))]
    return time_stream(rig_sequence(FRAMES[quick][rigs] + 20, rigs), 20, threads, backend=kind, refine=refine)


def against(other: str, repeats: int, quick: bool) -> None:
    """The head's cases of the checkout ``other`` and of this one, alternating, each in a fresh process."""
    trees = {"other": str(Path(other).resolve()), "this": str(Path(__file__).resolve().parents[1])}
    cases = [
        (kind, rigs, refine, THREADS)
        for rigs in (1, 64, 4096)
        for refine in (True, False)
        for kind in ("auto", "torch")
    ]
    cases += [("auto", 4096, True, 1)] * (THREADS > 1) + [("sequence", rigs, True, 0) for rigs in (1, 4096)]
    samples: dict[tuple, list[float]] = {}
    for r in range(repeats):
        for case in cases:
            for name in list(trees)[:: 1 - 2 * (r % 2)]:  # this one first every other round
                env = dict(os.environ, PYTHONPATH=trees[name])
                spec = json.dumps([*case, quick])
                out = subprocess.run(
                    [sys.executable, __file__, "--case", spec], env=env, capture_output=True, text=True
                )
                if out.returncode:
                    raise RuntimeError(f"{name} {case}: {out.stderr[-2000:]}")
                samples.setdefault((case, name), []).extend(json.loads(out.stdout.splitlines()[-1]))
    print(
        f"{'case':<44} {'other ms':>10} {'this ms':>10} {'this/other':>10}   (medians; load {os.getloadavg()[0]:.1f})"
    )
    rows = []
    for case in cases:
        kind, rigs, refine, threads = case
        label = {"auto": f"kernel, {threads} thr", "torch": "PyTorch", "sequence": "whole-sequence path"}[kind]
        name = f"{label}, {rigs} rig(s)" + ("" if kind == "sequence" else (", refined" if refine else ", closed form"))
        a, b = (statistics.median(samples[(case, tree)]) * 1e3 for tree in trees)
        rows.append({"case": name, "other_ms": a, "this_ms": b, "ratio": b / a, "n": len(samples[(case, "this")])})
        print(f"{name:<44} {a:>10.4f} {b:>10.4f} {b / a:>10.3f}", flush=True)
    write_json(OUT_AGAINST, {"other": shown_path(trees["other"]), "this": shown_path(trees["this"]), "rows": rows})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer repeats (a smoke run)")
    parser.add_argument("--repeats", type=int, default=3, help="interleaved repeats of the streaming cases")
    parser.add_argument(
        "--against", metavar="DIR", help="time the head of the ocalib checkout in DIR beside this one's"
    )
    parser.add_argument("--case", help=argparse.SUPPRESS)  # one case of --against, in this process: prints its times
    args = parser.parse_args()
    torch.set_num_threads(1)
    repeats = 1 if args.quick else args.repeats
    if args.case:
        print(json.dumps(time_case(*json.loads(args.case))))
        return
    if args.against:
        if not (Path(args.against) / "ocalib").is_dir():
            parser.error(f"--against {args.against}: no ocalib checkout there (no ocalib/ folder)")
        return against(args.against, repeats, args.quick)
    data = {rigs: rig_sequence(n + 20, rigs) for rigs, n in FRAMES[args.quick].items()}
    sequences = {rigs: rig_sequence(n, rigs) for rigs, n in SEQUENCE_FRAMES[args.quick].items()}
    samples: dict[tuple, list[float]] = {}
    with torch.inference_mode():  # compile the kernel (or load it from numba's cache) before timing
        OnlineCalibrator(2, batch_size=64)(data[64][0])
    for _ in range(repeats):
        for rigs, poses in data.items():
            warmup = min(20, len(poses) // 4)
            for refine in (True, False):
                for backend in ("auto", "torch"):
                    key = (backend, rigs, refine, THREADS)
                    samples.setdefault(key, []).extend(time_stream(poses, warmup, backend=backend, refine=refine))
            if rigs == 4096 and THREADS > 1:
                samples.setdefault(("auto", rigs, True, 1), []).extend(time_stream(poses, warmup, threads=1))
        for rigs, poses in sequences.items():
            samples.setdefault(("sequence", rigs, True, 0), []).append(time_sequence(poses))
    rows = []

    def add(name, per, samples, note=""):
        med = statistics.median(samples)
        rows.append({"case": name, "per": per, "median_ms": med * 1e3, "n": len(samples), "note": note})
        print(f"{name:<52} {med * 1e3:>10.3f} ms  per {per}  {note}", flush=True)

    print(f"torch {torch.__version__} ({torch.get_num_threads()} thread), numba {numba.__version__} ({THREADS} threads), "
          f"opencv {cv2.__version__}, load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cpus")  # fmt: skip
    for (kind, rigs, refine, threads), times in sorted(
        samples.items(), key=lambda kv: (kv[0][0] == "sequence", kv[0][1])
    ):
        label = "refined" if refine else "closed form"
        if kind == "auto":
            add(f"head, kernel, {rigs} rig(s), {label}, {threads} thr", "frame", times, "backend='auto' (the default)")
        elif kind == "torch":
            add(f"head, PyTorch, {rigs} rig(s), {label}", "frame", times, "backend='torch'")
        else:
            add(f"whole-sequence path, {rigs} rig(s)", "frame", times, f"{len(sequences[rigs])} frames at once")
    for n in (128, 1000):
        add(f"batch re-solve on N={n} frames", "frame", time_batch_resolve(n, 5 if n == 1000 else 20))
        for name, method in (("TSAI", cv2.CALIB_HAND_EYE_TSAI), ("PARK", cv2.CALIB_HAND_EYE_PARK)):
            reps = 1 if (n == 1000 and args.quick) else (3 if n == 1000 else 10)
            add(f"cv2.calibrateHandEye {name}, N={n}", "frame", time_opencv(n, reps, method), "one call on N poses")
    ms = {r["case"]: r["median_ms"] for r in rows}
    one = ms[f"head, kernel, 1 rig(s), refined, {THREADS} thr"]
    summary = {
        "one_rig_us": one * 1e3,
        "one_rig_closed_form_us": ms[f"head, kernel, 1 rig(s), closed form, {THREADS} thr"] * 1e3,
        "rigs_4096_ms": ms[f"head, kernel, 4096 rig(s), refined, {THREADS} thr"],
        "rigs_4096_one_thread_ms": ms.get("head, kernel, 4096 rig(s), refined, 1 thr"),
        "rigs_4096_closed_form_ms": ms[f"head, kernel, 4096 rig(s), closed form, {THREADS} thr"],
        "torch_one_rig_us": ms["head, PyTorch, 1 rig(s), refined"] * 1e3,
        "torch_rigs_4096_ms": ms["head, PyTorch, 4096 rig(s), refined"],
        "kernel_speedup_one_rig": ms["head, PyTorch, 1 rig(s), refined"] / one,
        "kernel_speedup_4096_rigs": ms["head, PyTorch, 4096 rig(s), refined"]
        / ms[f"head, kernel, 4096 rig(s), refined, {THREADS} thr"],
        "kernel_threads": THREADS,
        "sequence_1_rig_us_per_frame": ms["whole-sequence path, 1 rig(s)"] * 1e3,
        "sequence_4096_rigs_ms_per_frame": ms["whole-sequence path, 4096 rig(s)"],
        "speedup_vs_batch_resolve_N1000": ms["batch re-solve on N=1000 frames"] / one,
        "speedup_vs_opencv_tsai_N1000": ms["cv2.calibrateHandEye TSAI, N=1000"] / one,
        "targets": {"one_rig_us": 200, "rigs_4096_ms": 20},
        "load_average": os.getloadavg(),
    }
    print(json.dumps(summary, indent=1))
    write_json(OUT, {"rows": rows, "summary": summary})


if __name__ == "__main__":
    main()
