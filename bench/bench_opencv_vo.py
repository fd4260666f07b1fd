"""Benchmark of the classical front end (``ocalib.frontend.opencv_vo.OpenCVOdometry``) on rendered sequences.

    python bench/bench_opencv_vo.py [--presets handheld,front-left] [--frames 120] [--calib-frames 300]
                                    [--seed 1000] [--data data/synth/bench_vo] [--out bench/results/opencv_vo.json]

1. Per camera, on ``--frames`` frames (``ocalib synth --preset P --frames 120 --height 128 --width 416 --seed 1000``):
   median frame-to-frame rotation error (deg), translation direction error (deg), scale drift (coefficient of
   variation of the per-frame ``|t_pred| / |t_gt|``, which no global scale changes; and the ratio of its
   median over the last fifth to the first fifth), degenerate frames, and frames per second of ``step``
   (images preloaded as 8-bit grey).
2. Per preset, on ``--calib-frames`` frames: every camera's VO trajectory written as a KITTI file and fed to
   ``calibrate-poses`` (``calibrate_files``, defaults), against the rig's ground truth: rotation error,
   translation direction error, translation error (% of the baseline; camera 0's VO unit mapped to metres by
   a least-squares fit of its motions to the ground truth), the estimated scale against the true ratio of the
   two cameras' units. The same with the ground-truth poses as a reference.

Sequences are rendered into ``--data`` when missing. Prints tables and writes the JSON.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
from common import write_json

from ocalib.calib.poses.pipeline import calibrate_files
from ocalib.data import RigStream, open_sequence
from ocalib.eval.pose_metrics import frame_motions, step_errors
from ocalib.frontend.opencv_vo import OpenCVOdometry
from ocalib.geometry.se3 import rotation_angle_deg
from ocalib.io.poses import write_kitti
from ocalib.synth import preset, render_sequence


def sequence(name: str, frames: int, seed: int, height: int, width: int, root: Path):
    """The rendered sequence (rendered on first use)."""
    out = root / f"{name}_s{seed}_n{frames}_{height}x{width}"
    if not (out / "rig.yaml").is_file():
        cfg = preset(name).with_overrides(frames=frames, seed=seed, height=height, width=width)
        render_sequence(cfg, out, overwrite=True, workers=min(4, os.cpu_count() or 1))
    return open_sequence(out)


def run_vo(camera, images: list[np.ndarray] | None = None, **options) -> tuple[np.ndarray, np.ndarray, float]:
    """Poses (N, 4, 4), degenerate flags (N,) and frames per second of the VO with ``options`` on ``images`` (8-bit
    grey, preloaded; default: every frame of ``camera``)."""
    if images is None:
        images = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in camera.images]
    vo = OpenCVOdometry(camera.K, **options)
    poses, degenerate = [], []
    t0 = time.perf_counter()
    for image in images:
        vo.step(image)
        poses.append(vo.pose)
        degenerate.append(vo.status.degenerate)
    fps = len(images) / (time.perf_counter() - t0)
    return np.stack(poses), np.array(degenerate), fps


def vo_row(name: str, camera, poses, degenerate, fps) -> dict:
    e = step_errors(poses, camera.poses, ~degenerate)
    ratio = e["scale_ratio"]
    fifth = max(len(ratio) // 5, 1)
    return {
        "preset": name, "camera": camera.name, "frames": len(poses),
        "rotation_err_deg_median": float(np.median(e["rotation_deg"])),
        "rotation_err_deg_p90": float(np.percentile(e["rotation_deg"], 90)),
        "gt_rotation_deg_median": float(np.median(rotation_angle_deg(frame_motions(camera.poses)[:, :3, :3]))),
        "direction_err_deg_median": float(np.median(e["direction_deg"])),
        "direction_err_deg_p90": float(np.percentile(e["direction_deg"], 90)),
        "scale_cv": e["scale_cv"],
        "scale_drift_last_over_first_fifth": float(np.median(ratio[-fifth:]) / np.median(ratio[:fifth])),
        "degenerate_frames": int(degenerate[1:].sum()),
        "fps": fps,
    }  # fmt: skip


def _angle(a, b) -> float:
    return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


def calibration_row(name: str, seq, trajectories: list[np.ndarray], source: str) -> dict:
    """Calibrate camera 1 against camera 0 from ``trajectories`` and compare with the rig's ground truth."""
    with tempfile.TemporaryDirectory() as tmp:
        files = []
        for cam, poses in zip(seq.cameras, trajectories):
            files.append(Path(tmp) / f"{cam.name}.txt")
            write_kitti(files[-1], poses)
        doc = calibrate_files(files).result_json()
    est = doc["extrinsics"][0]
    truth = RigStream(seq).extrinsics[1].numpy()
    R, t = np.array(est["rotation"]), np.array(est["translation"])
    units = []  # metres per trajectory unit, per camera (least squares over the frame-to-frame motions)
    for cam, poses in zip(seq.cameras, trajectories):
        a, b = frame_motions(poses)[:, :3, 3], frame_motions(cam.poses)[:, :3, 3]
        units.append(float((a * b).sum() / (a * a).sum()))
    t_m, t_gt = t * units[0], truth[:3, 3]
    row = {
        "preset": name, "poses": source, "frames": len(trajectories[0]),
        "rotation_err_deg": float(rotation_angle_deg(R.T @ truth[:3, :3])),
        "translation_dir_err_deg": _angle(t_m, t_gt),
        "translation_err_pct_baseline": float(100 * np.linalg.norm(t_m - t_gt) / np.linalg.norm(t_gt)),
        "translation_m": t_m.tolist(), "translation_gt_m": t_gt.tolist(),
        "scale": est["scale"], "scale_true": units[1] / units[0],
        "planar_motion": est["observability"]["planar_motion"],
    }  # fmt: skip
    axes = est["observability"]["unobservable_translation_directions"]
    if axes:  # planar motion: compare in the observable plane only
        n = np.array(axes[0])
        row["translation_dir_err_deg_in_plane"] = _angle(t_m - (t_m @ n) * n, t_gt - (t_gt @ n) * n)
    return row


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--presets", default="handheld,front-left")
    p.add_argument("--frames", type=int, default=120)
    p.add_argument("--calib-frames", type=int, default=300, help="frames for the calibration check (0: skip)")
    p.add_argument("--seed", type=int, default=1000)
    p.add_argument("--height", type=int, default=128)
    p.add_argument("--width", type=int, default=416)
    p.add_argument("--data", default="data/synth/bench_vo")
    p.add_argument("--out", default="bench/results/opencv_vo.json")
    args = p.parse_args(argv)
    root = Path(args.data)
    vo_rows, calib_rows = [], []
    for name in args.presets.split(","):
        seq = sequence(name, args.frames, args.seed, args.height, args.width, root)
        for cam in seq.cameras:
            vo_rows.append(vo_row(name, cam, *run_vo(cam)))
        if args.calib_frames:
            seq = sequence(name, args.calib_frames, args.seed, args.height, args.width, root)
            runs = [run_vo(cam) for cam in seq.cameras]
            calib_rows.append(calibration_row(name, seq, [r[0] for r in runs], "opencv vo"))
            calib_rows.append(calibration_row(name, seq, [c.poses for c in seq.cameras], "ground truth"))
            for cam, r in zip(seq.cameras, runs):
                vo_rows.append(vo_row(name, cam, *r))

    print(
        "| preset | camera | frames | rot err med / p90 (deg) | GT rot/frame (deg) | dir err med / p90 (deg) "
        "| scale CV | drift last/first | degenerate | fps |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in vo_rows:
        print(
            f"| {r['preset']} | {r['camera']} | {r['frames']} | {r['rotation_err_deg_median']:.3f} / "
            f"{r['rotation_err_deg_p90']:.3f} | {r['gt_rotation_deg_median']:.2f} | "
            f"{r['direction_err_deg_median']:.2f} / {r['direction_err_deg_p90']:.1f} | {r['scale_cv']:.3f} | "
            f"{r['scale_drift_last_over_first_fifth']:.2f} | {r['degenerate_frames']} | {r['fps']:.1f} |"
        )
    if calib_rows:
        print(
            "\n| preset | poses | frames | rotation err (deg) | translation dir err (deg) | translation err "
            "(% baseline) | scale (true) | planar |"
        )
        print("|---|---|---|---|---|---|---|---|")
        for r in calib_rows:
            plane = r.get("translation_dir_err_deg_in_plane")
            direction = f"{r['translation_dir_err_deg']:.1f}" + (
                f" (in plane {plane:.1f})" if plane is not None else ""
            )
            print(
                f"| {r['preset']} | {r['poses']} | {r['frames']} | {r['rotation_err_deg']:.2f} | {direction} | "
                f"{r['translation_err_pct_baseline']:.0f} | {r['scale']:.3f} ({r['scale_true']:.3f}) | "
                f"{r['planar_motion']} |"
            )
    write_json(args.out, {"settings": vars(args), "vo": vo_rows, "calibration": calib_rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
