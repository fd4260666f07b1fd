"""The on-line rig estimator on held-out rendered rigs: accuracy at the end of the stream, the frame from which it
stays within the targets, cost per frame, peak memory, and change detection.

Each sequence (rendered by ``ocalib synth`` with a held-out seed when missing) is streamed through
:class:`~ocalib.rigba.online.OnlineRigEstimator` with camera 0's rendered poses as the metric trajectory, started
at the true rotations turned by 0.5 deg (the on-line head's typical error from images) with zero lever arms.
Reported per camera k >= 1: rotation error (deg), translation direction error (deg; on cars in the ground plane,
camera 0's y axis projected out: their height is not observable from planar motion) and translation error over
the baseline; the first frame from which the estimate stays within the targets (cars 0.5 deg, 5 deg, 0.1;
hand-held 0.5 deg, 10 deg, 0.25); seconds per keyframe (median) and per frame; the peak resident memory above the
start, and over the last third of the stream against the first two thirds (it must not grow); the changes found.

    python bench/bench_rig_online.py [--sequences handheld-1001 front-left-1008 ...] [--frames 300]
    python bench/bench_rig_online.py --change --out bench/results/rig_online_change.json

``--streaming N``: beside it, on the same sequence in the same run, the batch rig bundle adjustment streamed as
``ocalib calibrate --bundle-adjust-every N`` streams it (a run after every N frames on the frames so far, from the
network front end's head): its seconds per frame and its final errors.

``--metric-noise M``: the estimator takes the trajectory as M metres off (its positions priors, the rig's poses
solved); by default held, as the rendered poses are exact. ``--trajectory-error DEG``: the trajectory given is off
as a real one is (its rotation by a random walk of DEG a frame, its positions by 1 cm): held, the estimator reads
its error as the cameras moving.

``--change``: camera 1 is knocked at half the frames (2 deg about its y axis; on cars also 5 cm sideways); the
frame it is noticed at and the error against the new mounting at the end are reported, beside the error of a fresh
start on the frames after the change (what those frames alone can give). Without ``--change``, every
change found is a false alarm.
"""

from __future__ import annotations

import argparse
import dataclasses
import shutil
import time
from pathlib import Path

import cv2
import numpy as np
from bench_calibnet_accuracy import ensure
from bench_rigba import PeakMemory, rss_mb
from bench_rigba import run as run_bundle_adjustment
from common import add_sequence_arguments, write_json
from scipy.spatial.transform import Rotation

from ocalib.data.layout import open_sequence
from ocalib.geometry.se3 import rotation_angle_deg
from ocalib.rigba.online import OnlineRigEstimator, OnlineRigOptions
from ocalib.rigba.options import BundleOptions
from ocalib.sim.trajectory import off_trajectory
from ocalib.synth import preset, render_sequence
from ocalib.synth.presets import PRESETS, knocked

DEFAULT = ["handheld-1001", "front-left-1008", "handheld-1007", "front-left-2002", "handheld-2001", "front-left-1002"]
TARGETS = {"car": (0.5, 5.0, 0.1), "handheld": (0.5, 10.0, 0.25)}  # rotation deg, direction deg, translation / baseline


def ensure_knocked(root: Path, name: str, frames: int) -> Path:
    """``name`` rendered with camera 1 knocked at ``frames // 2`` (under ``root``, ``NAME-knocked``)."""
    path = root / f"{name}-knocked"
    if (path / "rig.yaml").exists():
        return path
    base = open_sequence(ensure(root, name, frames))  # for its preset and seed
    kind, seed = name.rsplit("-", 1)[0], int(name.rsplit("-", 1)[1])
    cfg = preset(kind).with_overrides(frames=frames, seed=seed, height=base.cameras[0].size[0],
                                      width=base.cameras[0].size[1])  # fmt: skip
    cfg = knocked(cfg, frames // 2)
    partial = path.with_name(path.name + ".partial")
    shutil.rmtree(partial, ignore_errors=True)
    render_sequence(cfg, partial, workers=2)
    partial.rename(path)
    return path


def errors(E: np.ndarray, T: np.ndarray, car: bool) -> tuple[float, float, float]:
    """Rotation error (deg), direction error (deg; on cars without camera 0's y), translation error / baseline."""
    project = np.diag([1.0, 0.0, 1.0]) if car else np.eye(3)
    t, t_true = project @ E[:3, 3], project @ T[:3, 3]
    cosine = t @ t_true / max(np.linalg.norm(t) * np.linalg.norm(t_true), 1e-300)
    return (
        float(rotation_angle_deg(E[:3, :3].T @ T[:3, :3])),
        float(np.degrees(np.arccos(np.clip(cosine, -1, 1)))),
        float(np.linalg.norm(t - t_true) / np.linalg.norm(t_true)),
    )


def drives(name: str) -> bool:
    """Whether held-out sequence ``name`` (PRESET-SEED..., e.g. surround-1001 or front-left-1008-knocked) is of a
    preset that drives (a car: the ground-plane comparison and the car's targets)."""
    presets = sorted((p for p in PRESETS if name.startswith(p + "-")), key=len)
    return bool(presets) and PRESETS[presets[-1]]["trajectory"]["kind"] == "drive"


def run(path: Path, frames: int, options: OnlineRigOptions, first: int = 0, trajectory_error: float = 0.0) -> dict:
    """The estimator over frames ``first`` to ``frames`` of ``path`` (from ``first`` on, a fresh start: the truth its
    start is turned from is the mounting at ``first``); camera 0's rendered poses the metric trajectory, off by
    ``trajectory_error`` (:func:`ocalib.sim.trajectory.off_trajectory`)."""
    seq = open_sequence(path)
    cams, frames = seq.cameras, min(frames, len(seq))
    car = drives(path.name)
    truth = np.stack([np.linalg.inv(cams[0].T_cam0_cam) @ c.T_cam0_cam for c in cams])
    after = truth.copy()
    for k, c in enumerate(cams):
        if c.change is not None:
            after[k] = np.linalg.inv(cams[0].T_cam0_cam) @ c.change.T_cam0_cam
            truth[k] = after[k] if first >= c.change.frame else truth[k]
    start = truth.copy()
    turn = Rotation.from_rotvec(np.radians(0.5) * np.array([1.0, 1.0, -1.0]) / np.sqrt(3)).as_matrix()
    start[1:, :3, :3] = turn @ truth[1:, :3, :3]
    poses = off_trajectory(cams[0].poses, trajectory_error) if trajectory_error else cams[0].poses
    poses = np.linalg.inv(poses[first : first + 1]) @ poses
    estimator = OnlineRigEstimator(np.stack([c.K for c in cams]), [tuple(c.size) for c in cams], start, options)
    states, rss = [], []
    with PeakMemory() as memory:
        begin = time.perf_counter()
        for t in range(first, frames):
            images = [cv2.imread(str(c.images[t]), cv2.IMREAD_GRAYSCALE) for c in cams]
            state = estimator.update(t, images, poses[t])
            if state is not None:
                states.append(state)
                rss.append(rss_mb())
        seconds = time.perf_counter() - begin
    kind = "car" if car else "handheld"
    out = {"cameras": {}, "seconds_per_frame": seconds / (frames - first), "peak_mb": memory.peak,
           "seconds_per_keyframe_median": float(np.median([s.seconds for s in states])),
           "rss_mb_first_two_thirds_max": float(max(rss[: 2 * len(rss) // 3])),
           "rss_mb_last_third_max": float(max(rss[2 * len(rss) // 3 :])),
           "keyframes_unregistered": estimator.keyframes_unregistered}  # fmt: skip
    for k in range(1, len(cams)):
        change = cams[k].change.frame if cams[k].change is not None else None
        within = [
            all(
                e <= bound
                for e, bound in zip(
                    errors(s.extrinsics[k], after[k] if change and s.frame >= change else truth[k], car), TARGETS[kind]
                )
            )  # fmt: skip
            for s in states
        ]
        settled = next((states[i].frame for i in range(len(states)) if all(within[i:])), None)
        found = [{"frame": c.frame, "detected": c.detected, "rotation_change_deg": c.rotation_change_deg,
                  "translation_change": c.translation_change} for s in states for j, c in s.changes if j == k]  # fmt: skip
        out["cameras"][cams[k].name] = {
            "final": dict(
                zip(
                    ("rotation_deg", "direction_deg", "translation_rel_baseline"),
                    errors(states[-1].extrinsics[k], after[k], car),
                )
            ),  # fmt: skip
            "stays_within_targets_from_frame": settled,
            "true_change_frame": change,
            "changes": found,
            "dismissed_candidates": [
                {"frame": f, "split_statistic": x.statistic, "rotation_change_deg": x.rotation_deg}
                for j, f, x in estimator.dismissed
                if j == k
            ],
        }
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_sequence_arguments(p, DEFAULT)
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--change", action="store_true", help="camera 1 knocked at half the frames")
    p.add_argument("--keyframe-step", type=int, default=OnlineRigOptions.keyframe_step)
    p.add_argument("--window", type=int, default=OnlineRigOptions.window)
    p.add_argument("--streaming", type=int, metavar="N", help="also the bundle adjustment after every N frames")
    p.add_argument(
        "--metric-noise",
        type=float,
        default=0.0,
        help="the estimator's: the trajectory's stated noise, m (default 0: held, the rendered poses exact)",
    )
    p.add_argument(
        "--trajectory-error",
        type=float,
        default=0.0,
        metavar="DEG",
        help="the trajectory's rotation off by a random walk of DEG a frame, its positions by 1 cm",
    )
    p.add_argument("--out", default="bench/results/rig_online.json")
    args = p.parse_args()
    cv2.setNumThreads(1)
    options = OnlineRigOptions(keyframe_step=args.keyframe_step, window=args.window, metric_noise=args.metric_noise)
    results = {}
    print(f"{'sequence':24} {'camera':8} {'rot':>6} {'dir':>6} {'t/b':>6} {'within from':>11} {'ms/frame':>8} "
          f"{'MB':>5} {'changes (frame, noticed)':>26}")  # fmt: skip
    for name in args.sequences:
        root = Path(args.root)
        path = ensure_knocked(root, name, args.frames) if args.change else ensure(root, name, args.frames)
        r = results[path.name] = run(path, args.frames, options, trajectory_error=args.trajectory_error)
        if args.streaming:
            streamed = run_bundle_adjustment(path, "network", args.frames, BundleOptions(), args.streaming)
            r["streaming_bundle_adjustment"] = {"every": args.streaming} | {
                key: streamed[key] for key in ("bundle", "stage_seconds_per_frame", "stage_peak_mb", "trusted")
            }
            print(f"{path.name:24} bundle adjustment every {args.streaming} frames: "
                  f"{1000 * streamed['stage_seconds_per_frame']:.0f} ms/frame, {streamed['stage_peak_mb']:.0f} MB, "
                  f"final {streamed['bundle']}", flush=True)  # fmt: skip
        knocks = [c["true_change_frame"] for c in r["cameras"].values() if c["true_change_frame"] is not None]
        if knocks:  # the reference for the re-convergence: a fresh start on the frames after the change
            r["fresh_after_change"] = run(path, args.frames, options, min(knocks), args.trajectory_error)
            for camera, c in r["fresh_after_change"]["cameras"].items():
                f = c["final"]
                print(
                    f"{path.name:24} {camera:8} a fresh start at frame {min(knocks)}: {f['rotation_deg']:.2f} / "
                    f"{f['direction_deg']:.1f} / {f['translation_rel_baseline']:.2f}",
                    flush=True,
                )
        for camera, c in r["cameras"].items():
            f = c["final"]
            print(
                f"{path.name:24} {camera:8} {f['rotation_deg']:6.2f} {f['direction_deg']:6.1f} "
                f"{f['translation_rel_baseline']:6.2f} {str(c['stays_within_targets_from_frame']):>11} "
                f"{1000 * r['seconds_per_frame']:8.0f} {r['peak_mb']:5.0f} "
                f"{str([(x['frame'], x['detected']) for x in c['changes']]):>26}",
                flush=True,
            )
        doc = {"frames": args.frames, "change": args.change, "options": dataclasses.asdict(options),
               "trajectory_error_deg": args.trajectory_error, "results": results}  # fmt: skip
        write_json(args.out, doc)  # after every sequence: an interrupted run keeps what it measured


if __name__ == "__main__":
    main()
