"""Throughput of ``ocalib calibrate-poses`` on 20,000 frames beside one OpenCV ``calibrateHandEye`` call on 1,000.

The target: calibrate-poses on 20,000 frames faster than one ``calibrateHandEye`` call on 1,000
poses. Both run in the same process on the same simulated rig (the paper's linear dynamic system, noise
0.001 on every pose, camera 1 in units of scale 2). The pose files are written to a temporary folder
first (not timed); then timed: the pipeline in-process (read + associate, stream every frame through
the on-line head, result JSON and trace CSV written), and the whole command as a subprocess (adds the
Python start and the torch import). Side by side: the streaming stage (``calibrate_rig``) with the head's change test
and without it (``change_test=None``), alternating, ``--repeats`` times each; medians, and their ratio.

Mapping to OpenCV (as ``bench_opencv_accuracy.py``). Convention: OpenCV's gripper is camera 0 and its
camera is camera 1, so ``X = T_cam2gripper = T_cam0_cam1``: ``T_gripper2base`` = camera 0's
camera-to-world poses, ``T_target2cam`` = the inverse of camera 1's (in camera-0 units: OpenCV has no
scale). The first 1,000 frames of the same trajectory.

Usage: ``python bench/bench_calibrate_poses.py [--frames N] [--opencv-poses N] [--repeats N]`` -- prints a table
and writes ``bench/results/calibrate_poses.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import torch
from common import write_json

from ocalib.calib.drivers.change import ChangeTest
from ocalib.calib.poses.pipeline import RigPoses, calibrate_rig, load_rig
from ocalib.io.poses import write_kitti
from ocalib.sim.trajectory import add_noise, lds_trajectory, random_rig, rig_trajectories

ROOT = Path(__file__).resolve().parents[1]
SCALE = 2.0
NOISE = 1e-3
OPENCV = {"TSAI": cv2.CALIB_HAND_EYE_TSAI, "PARK": cv2.CALIB_HAND_EYE_PARK}


def simulate(frames: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """-> poses (frames, 2, 4, 4) camera-to-world (camera 1 in units of SCALE) and the true T_cam0_cam1."""
    g = torch.Generator().manual_seed(seed)
    X = random_rig(g)
    poses = rig_trajectories(lds_trajectory(frames, g), X[None], torch.tensor([SCALE], dtype=torch.float64))
    return add_noise(poses, NOISE, g).numpy(), X.numpy()


def errors(R: np.ndarray, t: np.ndarray, X: np.ndarray) -> tuple[float, float]:
    """Rotation error (deg) and translation error (camera-0 units) against the truth X (4, 4)."""
    cos = (np.trace(R.T @ X[:3, :3]) - 1) / 2
    return math.degrees(math.acos(np.clip(cos, -1, 1))), float(np.linalg.norm(t - X[:3, 3]))


def run_pipeline(files: list[str], out_dir: Path) -> tuple[dict, dict]:
    """Time the in-process pipeline -> (seconds per stage, result JSON)."""
    t0 = time.perf_counter()
    rig = load_rig(files)
    t1 = time.perf_counter()
    run = calibrate_rig(rig)
    t2 = time.perf_counter()
    doc = run.result_json()
    (out_dir / "result.json").write_text(json.dumps(doc))
    run.write_trace(out_dir / "trace.csv")
    t3 = time.perf_counter()
    return {"read": t1 - t0, "stream": t2 - t1, "write": t3 - t2, "total": t3 - t0}, doc


def change_test_cost(rig: RigPoses, repeats: int) -> dict:
    """The streaming stage with the change test and without it, alternating ``repeats`` times -> seconds (each run),
    their medians per frame (us) and the ratio of the medians."""
    seconds = {"on": [], "off": []}
    for _ in range(repeats):
        for case, test in (("on", ChangeTest()), ("off", None)):
            t = time.perf_counter()
            calibrate_rig(rig, change_test=test)
            seconds[case].append(time.perf_counter() - t)
    us = {case: float(np.median(v)) / len(rig.poses) * 1e6 for case, v in seconds.items()}
    return {
        "repeats": repeats,
        "stream_seconds": seconds,
        "stream_us_per_frame_on": us["on"],
        "stream_us_per_frame_off": us["off"],
        "on_over_off": us["on"] / us["off"],
        "change_test_us_per_frame": us["on"] - us["off"],
    }


def run_cli(files: list[str], out_dir: Path) -> float:
    """Time ``python -m ocalib calibrate-poses`` as a user runs it (JSON and trace written)."""
    cmd = [sys.executable, "-m", "ocalib", "calibrate-poses", *files,
           "--out", str(out_dir / "cli.json"), "--trace", str(out_dir / "cli.csv")]  # fmt: skip
    t = time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True, cwd=ROOT)
    return time.perf_counter() - t


def run_opencv(poses: np.ndarray, X: np.ndarray) -> dict[str, dict]:
    """One calibrateHandEye call per method on ``poses`` (N, 2, 4, 4) -> seconds and errors."""
    cam0, cam1 = poses[:, 0], poses[:, 1].copy()
    cam1[:, :3, 3] *= SCALE  # OpenCV has no scale: give it camera 1 in camera-0 units
    target2cam = np.linalg.inv(cam1)
    out = {}
    for name, method in OPENCV.items():
        t = time.perf_counter()
        R, tr = cv2.calibrateHandEye(
            list(cam0[:, :3, :3]),
            list(cam0[:, :3, 3]),
            list(target2cam[:, :3, :3]),
            list(target2cam[:, :3, 3]),
            method=method,
        )
        seconds = time.perf_counter() - t
        rot, trans = errors(R, tr.ravel(), X)
        out[name] = {"seconds": seconds, "rotation_error_deg": rot, "translation_error": trans}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=20_000)
    parser.add_argument("--opencv-poses", type=int, default=1_000)
    parser.add_argument("--repeats", type=int, default=5, help="runs of each side of the change test's side by side")
    args = parser.parse_args()

    poses, X = simulate(max(args.frames, args.opencv_poses))
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        files = [str(tmp / f"cam{c}.txt") for c in range(2)]
        for c, f in enumerate(files):
            write_kitti(f, poses[: args.frames, c])
        stages, doc = run_pipeline(files, tmp)
        cli = run_cli(files, tmp)
        change = change_test_cost(load_rig(files), args.repeats)
    cam = doc["extrinsics"][0]
    rot, trans = errors(np.array(cam["rotation"]), np.array(cam["translation"]), X)
    opencv = run_opencv(poses[: args.opencv_poses], X)
    fastest = min(v["seconds"] for v in opencv.values())

    rows = [
        (f"calibrate-poses, pipeline ({args.frames} frames)", stages["total"], rot, trans),
        (f"calibrate-poses, CLI process ({args.frames} frames)", cli, rot, trans),
    ] + [(f"cv2.calibrateHandEye {m} ({args.opencv_poses} poses)", v["seconds"], v["rotation_error_deg"],
          v["translation_error"]) for m, v in opencv.items()]  # fmt: skip
    print(f"{'':52s} {'seconds':>8s} {'x fastest cv2':>13s} {'rot err deg':>11s} {'trans err':>10s}")
    for name, seconds, r, t in rows:
        print(f"{name:52s} {seconds:8.2f} {seconds / fastest:13.2f} {r:11.4f} {t:10.4f}")
    print(
        f"pipeline stages: read {stages['read']:.2f} s, stream {stages['stream']:.2f} s "
        f"({stages['stream'] / args.frames * 1e6:.0f} us/frame), write {stages['write']:.2f} s; "
        f"scale {cam['scale']:.5f} (true {SCALE})"
    )
    print(
        f"stream, medians of {args.repeats}: with the change test {change['stream_us_per_frame_on']:.1f} us/frame, "
        f"without {change['stream_us_per_frame_off']:.1f} us/frame; ratio {change['on_over_off']:.2f} "
        f"(the test {change['change_test_us_per_frame']:.1f} us/frame)"
    )

    result = {
        "frames": args.frames,
        "opencv_poses": args.opencv_poses,
        "noise": NOISE,
        "pipeline_seconds": stages,
        "pipeline_us_per_frame": stages["total"] / args.frames * 1e6,
        "cli_seconds": cli,
        "ours": {"rotation_error_deg": rot, "translation_error": trans, "scale": cam["scale"], "true_scale": SCALE},
        "opencv": opencv,
        "pipeline_over_fastest_opencv": stages["total"] / fastest,
        "cli_over_fastest_opencv": cli / fastest,
        "change_test": change,
    }
    write_json(ROOT / "bench" / "results" / "calibrate_poses.json", result)


if __name__ == "__main__":
    main()
