"""Per-frame cost of the on-line calibration head against re-solving from scratch every frame.

Measures, in one run on this machine:
* the head's per-frame update (``OnlineCalibrator.forward``) for 1, 64 and 4096 rigs batched;
* re-solving the batch problem (``batch_calibrate``) on all N frames so far, which is what a
  non-recursive method pays per frame, and one ``cv2.calibrateHandEye`` call on N poses (OpenCV builds
  motions from all pose pairs), both at N = 128 and 1000.

Prints a table and writes ``bench/results/online.json``. Medians over repeats.

    python bench/bench_online.py [--quick]
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from pathlib import Path

import cv2
import numpy as np
import torch

from ocalib.calib.batch import batch_calibrate
from ocalib.calib.online import OnlineCalibrator
from ocalib.sim.trajectory import add_noise, lds_trajectory, random_rig, rig_trajectories

OUT = Path(__file__).parent / "results" / "online.json"


def rig_sequence(frames: int, rigs: int, seed: int = 0) -> torch.Tensor:
    """(frames, rigs, 2, 4, 4) noisy LDS trajectories of random rigs."""
    g = torch.Generator().manual_seed(seed)
    seqs = [add_noise(rig_trajectories(lds_trajectory(frames, g), random_rig(g)[None]), 0.01, g) for _ in range(min(rigs, 8))]
    return torch.stack([seqs[i % len(seqs)] for i in range(rigs)], 1)


def time_stream(rigs: int, frames: int, warmup: int = 40) -> list[float]:
    poses = rig_sequence(frames + warmup, rigs)
    cal = OnlineCalibrator(2, batch_size=rigs)
    times = []
    with torch.inference_mode():
        for t in range(frames + warmup):
            start = time.perf_counter()
            cal(poses[t])
            if t >= warmup:
                times.append(time.perf_counter() - start)
    return times


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
    args = parser.parse_args()
    torch.set_num_threads(2)
    frames = 50 if args.quick else 300
    rows = []

    def add(name, per, samples, note=""):
        med = statistics.median(samples)
        rows.append({"case": name, "per": per, "median_ms": med * 1e3, "n": len(samples), "note": note})
        print(f"{name:<44} {med * 1e3:>10.3f} ms  per {per}  {note}", flush=True)

    print(f"torch {torch.__version__}, opencv {cv2.__version__}, {torch.get_num_threads()} threads, {platform.processor()}")
    for rigs in (1, 64, 4096):
        add(f"on-line head, {rigs} rig(s)", "frame", time_stream(rigs, frames if rigs < 4096 else frames // 5))
    for n in (128, 1000):
        add(f"batch re-solve on N={n} frames", "frame", time_batch_resolve(n, 5 if n == 1000 else 20))
        for name, method in (("TSAI", cv2.CALIB_HAND_EYE_TSAI), ("PARK", cv2.CALIB_HAND_EYE_PARK)):
            repeats = 1 if (n == 1000 and args.quick) else (3 if n == 1000 else 10)
            add(f"cv2.calibrateHandEye {name}, N={n}", "frame", time_opencv(n, repeats, method), "one call on N poses")
    online = {r["case"]: r["median_ms"] for r in rows}
    one = online["on-line head, 1 rig(s)"]
    summary = {
        "one_rig_us": one * 1e3,
        "rigs_4096_ms": online["on-line head, 4096 rig(s)"],
        "speedup_vs_batch_resolve_N1000": online["batch re-solve on N=1000 frames"] / one,
        "speedup_vs_opencv_tsai_N1000": online["cv2.calibrateHandEye TSAI, N=1000"] / one,
    }
    print(json.dumps(summary, indent=1))
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps({"rows": rows, "summary": summary, "torch": torch.__version__, "opencv": cv2.__version__}, indent=1))


if __name__ == "__main__":
    main()
