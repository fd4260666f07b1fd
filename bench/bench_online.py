"""Per-frame cost of the on-line calibration head against re-solving from scratch every frame.

Measures, in one run on this machine (one intra-op thread: on this shared 2-core machine two threads were
10x slower for 4096 rigs):
* the head's per-frame update (``OnlineCalibrator.forward``, reading the estimate) for 1, 64 and 4096 rigs
  batched, with the joint refinement (the default) and without (``refine=False``, the closed form);
* the same through ``torch.compile`` (one graph, C++ wrapper) for 1 and 4096 rigs, and for 1 rig in the leanest
  configuration (frame-0 pairing, one direction, closed form): the floor of a compiled head on this CPU;
* the whole-sequence path (``calibrate_sequence``: the same estimates for a recorded sequence), per frame;
* the floor: the paper's algorithm alone (frame-0 motions, one incremental-SVD step, one RLS step), composed from
  the library's pure functions with none of the head's bookkeeping (no pose checks, gating, robust weights,
  observability, history), eager and compiled, for 1 and 4096 rigs;
* re-solving the batch problem (``batch_calibrate``, closed form) on all N frames so far, which is what a
  non-recursive method pays per frame, and one ``cv2.calibrateHandEye`` call on N poses (OpenCV builds
  motions from all pose pairs), both at N = 128 and 1000.

Prints a table and writes ``bench/results/online.json``. Medians over repeats; the streaming cases run
interleaved, ``--repeats`` times, so that a change in the machine's load hits all of them alike.

    python bench/bench_online.py [--quick]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

import cv2
import numpy as np
import torch

from common import write_json
from ocalib.calib.batch import batch_calibrate
from ocalib.calib.handeye import rotation_block, translation_rows
from ocalib.calib.online import OnlineCalibrator
from ocalib.calib.rotation import incremental_svd_update, rotation_solution
from ocalib.calib.translation import rls_update
from ocalib.calib.sequence import calibrate_sequence
from ocalib.geometry.pose import relative_pose
from ocalib.geometry.quaternion import quaternion_to_rotation_matrix, rotation_matrix_to_quaternion
from ocalib.sim.trajectory import add_noise, lds_trajectory, random_rig, rig_trajectories

OUT = Path(__file__).parent / "results" / "online.json"
LEAN = {"motion": "first", "symmetric": False, "refine": False}  # the fewest operations a frame


def rig_sequence(frames: int, rigs: int, seed: int = 0) -> torch.Tensor:
    """(frames, rigs, 2, 4, 4) noisy LDS trajectories of random rigs."""
    g = torch.Generator().manual_seed(seed)
    seqs = [add_noise(rig_trajectories(lds_trajectory(frames, g), random_rig(g)[None]), 0.01, g) for _ in range(min(rigs, 8))]
    return torch.stack([seqs[i % len(seqs)] for i in range(rigs)], 1)


def time_stream(poses: torch.Tensor, warmup: int = 20, compiled: bool = False, **options) -> list[float]:
    """Seconds per frame of the head (forward + reading the estimate) on poses (T, B, 2, 4, 4); ``compiled``:
    through ``torch.compile`` (one graph, C++ wrapper; the compile itself is the first frame's, not counted)."""
    cal = OnlineCalibrator(2, batch_size=poses.shape[1], **options)
    if compiled:
        import torch._inductor.config as inductor

        inductor.cpp_wrapper = True
        cal = torch.compile(cal, fullgraph=True, dynamic=False)
    times = []
    with torch.inference_mode():
        for t in range(len(poses)):
            start = time.perf_counter()
            cal(poses[t]).rotation.sum()
            if t >= warmup:
                times.append(time.perf_counter() - start)
    return times


def paper_step(first, S2, V, x, C, poses):
    """One frame of the paper's algorithm alone on poses (B, 2, 4, 4): the motions from frame 0, one incremental-SVD
    step, one RLS step. No pose checks, gating, robust weights, observability or history: the floor under any head
    that runs the paper's equations with torch operations."""
    motion = relative_pose(first, poses)
    q = rotation_matrix_to_quaternion(motion[..., :3, :3])
    S2, V = incremental_svd_update(S2, V, rotation_block(q[:, 0], q[:, 1]))
    dR = quaternion_to_rotation_matrix(rotation_solution(V))
    B, b = translation_rows(motion[:, 0, :3, :3], motion[:, 0, :3, 3], motion[:, 1, :3, 3], dR)
    x, C = rls_update(x, C, B, b)
    return S2, V, x, C, dR


def time_paper_floor(poses: torch.Tensor, warmup: int = 20, compiled: bool = False) -> list[float]:
    """Seconds per frame of :func:`paper_step` on poses (T, B, 2, 4, 4), eager or compiled (as :func:`time_stream`)."""
    rigs, f = poses.shape[1], dict(dtype=poses.dtype)
    state = (torch.zeros(rigs, 4, **f), torch.eye(4, **f).expand(rigs, 4, 4), torch.zeros(rigs, 4, **f),
             1e4 * torch.eye(4, **f).expand(rigs, 4, 4))  # fmt: skip
    step = torch.compile(paper_step, fullgraph=True, dynamic=False) if compiled else paper_step
    times = []
    with torch.inference_mode():
        for t in range(1, len(poses)):
            start = time.perf_counter()
            *state, dR = step(poses[0], *state, poses[t])
            dR.sum()
            if t > warmup:
                times.append(time.perf_counter() - start)
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer repeats (a smoke run)")
    parser.add_argument("--repeats", type=int, default=3, help="interleaved repeats of the streaming cases")
    args = parser.parse_args()
    torch.set_num_threads(1)
    repeats = 1 if args.quick else args.repeats
    frames = {1: 300, 64: 200, 4096: 16} if not args.quick else {1: 40, 64: 30, 4096: 4}
    data = {rigs: rig_sequence(n + 20, rigs) for rigs, n in frames.items()}
    sequences = {1: rig_sequence(2000 if not args.quick else 200, 1), 4096: rig_sequence(32 if not args.quick else 8, 4096)}
    samples: dict[tuple, list[float]] = {}
    for _ in range(repeats):
        for rigs, poses in data.items():
            for refine in (True, False):
                samples.setdefault(("stream", rigs, refine), []).extend(time_stream(poses, refine=refine))
            samples.setdefault(("floor", rigs, False), []).extend(time_paper_floor(poses, warmup=min(20, len(poses) // 4)))
        for rigs, poses in sequences.items():
            samples.setdefault(("sequence", rigs, True), []).append(time_sequence(poses))
    for rigs in (1, 4096):  # compiled once (each compile takes about a minute on this CPU)
        compiled_start = time.perf_counter()
        samples[("compiled", rigs, True)] = time_stream(data[rigs], warmup=min(20, len(data[rigs]) // 4), compiled=True)
        print(f"compiled {rigs} rig(s) in {time.perf_counter() - compiled_start:.0f} s (with the timed frames)")
    samples[("compiled-lean", 1, False)] = time_stream(data[1], compiled=True, **LEAN)
    for rigs in (1, 4096):
        samples[("floor-compiled", rigs, False)] = time_paper_floor(data[rigs], min(20, len(data[rigs]) // 4), True)
    rows = []

    def add(name, per, samples, note=""):
        med = statistics.median(samples)
        rows.append({"case": name, "per": per, "median_ms": med * 1e3, "n": len(samples), "note": note})
        print(f"{name:<52} {med * 1e3:>10.3f} ms  per {per}  {note}", flush=True)

    print(f"torch {torch.__version__}, opencv {cv2.__version__}, {torch.get_num_threads()} thread, "
          f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cpus")  # fmt: skip
    for (kind, rigs, refine), times in samples.items():
        label = "refined" if refine else "closed form"
        if kind == "stream":
            add(f"on-line head, {rigs} rig(s), {label}", "frame", times)
        elif kind == "compiled":
            add(f"on-line head, {rigs} rig(s), {label}, torch.compile", "frame", times, "one graph, C++ wrapper")
        elif kind == "compiled-lean":
            add(f"on-line head, {rigs} rig(s), leanest, torch.compile", "frame", times, f"{LEAN}")
        elif kind.startswith("floor"):
            how = ", torch.compile" if kind == "floor-compiled" else ""
            add(f"floor: paper's algorithm alone, {rigs} rig(s){how}", "frame", times, "no checks, gating, observability")
        else:
            add(f"whole-sequence path, {rigs} rig(s)", "frame", times, f"{len(sequences[rigs])} frames at once")
    for n in (128, 1000):
        add(f"batch re-solve on N={n} frames", "frame", time_batch_resolve(n, 5 if n == 1000 else 20))
        for name, method in (("TSAI", cv2.CALIB_HAND_EYE_TSAI), ("PARK", cv2.CALIB_HAND_EYE_PARK)):
            reps = 1 if (n == 1000 and args.quick) else (3 if n == 1000 else 10)
            add(f"cv2.calibrateHandEye {name}, N={n}", "frame", time_opencv(n, reps, method), "one call on N poses")
    ms = {r["case"]: r["median_ms"] for r in rows}
    one = ms["on-line head, 1 rig(s), refined"]
    summary = {
        "one_rig_us": one * 1e3,
        "one_rig_closed_form_us": ms["on-line head, 1 rig(s), closed form"] * 1e3,
        "rigs_4096_ms": ms["on-line head, 4096 rig(s), refined"],
        "rigs_4096_closed_form_ms": ms["on-line head, 4096 rig(s), closed form"],
        "one_rig_compiled_us": ms["on-line head, 1 rig(s), refined, torch.compile"] * 1e3,
        "rigs_4096_compiled_ms": ms["on-line head, 4096 rig(s), refined, torch.compile"],
        "one_rig_compiled_leanest_us": ms["on-line head, 1 rig(s), leanest, torch.compile"] * 1e3,
        "floor_one_rig_us": ms["floor: paper's algorithm alone, 1 rig(s)"] * 1e3,
        "floor_one_rig_compiled_us": ms["floor: paper's algorithm alone, 1 rig(s), torch.compile"] * 1e3,
        "floor_4096_rigs_ms": ms["floor: paper's algorithm alone, 4096 rig(s)"],
        "floor_4096_rigs_compiled_ms": ms["floor: paper's algorithm alone, 4096 rig(s), torch.compile"],
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
