"""A rendered car written as a KITTI raw *extract* drive, as the real product comes, calibrated by ``ocalib
calibrate`` without any preparation by hand.

The drive: both cameras with a KITTI-like lens (OpenCV's model, rendered exactly), each dropping a frame of its own
and stamping its frames on its own clock (camera 1 ``LATE`` later), ``calib_cam_to_cam.txt`` with ``S_0x``, ``K_0x``,
``D_0x``, ``R_0x``, ``T_0x``, and OXTS packets at 100 Hz (camera 0's rendered path through a fixed IMU mounting,
interpolated between frames) with a gap, their own ``timestamps.txt``, ``calib_velo_to_cam.txt`` and
``calib_imu_to_velo.txt``. Then ``ocalib calibrate --sequence DRIVE --metric-trajectory sequence`` (the OXTS
trajectory), with the defaults and with ``--no-bundle-adjust``, and its errors against the truth in the calibration
file; the car's targets: 0.5 deg, 5 deg of direction in the ground plane, 0.1 baselines.

    python bench/bench_kitti_extract.py [--seed 7101] [--frames 300] [--root data/eval]

Writes ``bench/results/kitti_extract.json``.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from dataclasses import replace
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
from common import write_json

from ocalib.data.distortion import Distortion
from ocalib.data.kitti_raw import poses_to_oxts
from ocalib.data.layout import open_sequence
from ocalib.io.timing import interpolate
from ocalib.synth import preset
from ocalib.synth.sequence import render_sequence

LENS = (-0.12, 0.03, 0.0005, -0.0003, 0.0)  # k1 k2 p1 p2 k3: a KITTI-like barrel at this field of view
DROPPED = (37, 212)  # the frame each camera drops
LATE = 0.001  # seconds camera 1 stamps after camera 0
OXTS_RATE = 100.0
OXTS_GAP = (15.0, 15.08)  # seconds of the drive without OXTS packets
T_VELO_IMU = np.array([[1, 0, 0, -0.81], [0, 1, 0, 0.32], [0, 0, 1, -0.8], [0, 0, 0, 1.0]])
T_CAM0_VELO = np.array([[0, -1, 0, 0.0], [0, 0, -1, -0.08], [1, 0, 0, -0.27], [0, 0, 0, 1.0]])
EPOCH = datetime(2011, 9, 26, 13, 2, 25, tzinfo=timezone.utc).timestamp()


def stamp(t: float) -> str:
    """KITTI's stamp of ``t`` seconds after the drive's start."""
    whole = datetime.fromtimestamp(EPOCH + int(t), tz=timezone.utc)
    return f"{whole:%Y-%m-%d %H:%M:%S}.{round((t % 1) * 1e9):09d}"


def kv(**entries) -> str:
    return "".join(f"{k}: {' '.join(f'{v:.12e}' for v in np.ravel(a))}\n" for k, a in entries.items())


def write_extract(rendered: Path, root: Path) -> Path:
    """The rendered rig at ``rendered`` as an extract drive under ``root`` -> the drive folder."""
    seq = open_sequence(rendered)
    drive = root / "2011_09_26" / "2011_09_26_drive_0001_extract"
    shutil.rmtree(drive.parent, ignore_errors=True)
    calib = ""
    times = seq.times
    for i, (cam, drop) in enumerate(zip(seq.cameras, DROPPED)):
        kept = [t for t in range(len(cam)) if t != drop]
        folder = drive / f"image_0{i}"
        (folder / "data").mkdir(parents=True)
        for j, t in enumerate(kept):
            shutil.copy(cam.images[t], folder / "data" / f"{j:010d}.png")
        (folder / "timestamps.txt").write_text("".join(f"{stamp(times[t] + LATE * i)}\n" for t in kept))
        T = np.linalg.inv(cam.T_cam0_cam)  # camera 0's points into this camera's
        height, width = cam.size
        calib += kv(**{f"S_0{i}": [width, height], f"K_0{i}": cam.K, f"D_0{i}": cam.distortion.coeffs,
                       f"R_0{i}": T[:3, :3], f"T_0{i}": T[:3, 3]})  # fmt: skip
    (drive.parent / "calib_cam_to_cam.txt").write_text("calib_time: 09-Jan-2012 13:57:47\n" + calib)
    (drive.parent / "calib_velo_to_cam.txt").write_text(kv(R=T_CAM0_VELO[:3, :3], T=T_CAM0_VELO[:3, 3]))
    (drive.parent / "calib_imu_to_velo.txt").write_text(kv(R=T_VELO_IMU[:3, :3], T=T_VELO_IMU[:3, 3]))
    t = np.arange(times[0], times[-1] + 1e-9, 1 / OXTS_RATE)
    t = t[(t < OXTS_GAP[0]) | (t > OXTS_GAP[1])]
    kept, cam0, _ = interpolate(t, times, seq.cameras[0].poses, max_dt=1.0)
    t, imu = t[kept], cam0 @ T_CAM0_VELO @ T_VELO_IMU
    (drive / "oxts" / "data").mkdir(parents=True)
    for j, packet in enumerate(poses_to_oxts(imu)):
        (drive / "oxts" / "data" / f"{j:010d}.txt").write_text(" ".join(f"{v:.15g}" for v in packet) + "\n")
    (drive / "oxts" / "timestamps.txt").write_text("".join(f"{stamp(s)}\n" for s in t))
    return drive


def calibrate(drive: Path, out: Path, bundle_adjust: bool) -> dict:
    command = [sys.executable, "-m", "ocalib", "calibrate", "--sequence", str(drive), "--metric-trajectory",
               "sequence", "--out", str(out)] + ([] if bundle_adjust else ["--no-bundle-adjust"])  # fmt: skip
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"ocalib calibrate failed ({done.returncode}): {done.stderr.strip()[-800:]}")
    return json.loads(out.read_text())


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seed", type=int, default=7101)
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--root", default="data/eval")
    p.add_argument("--out", default="bench/results/kitti_extract.json")
    args = p.parse_args()
    root = Path(args.root)
    name = f"front-left-{args.seed}-lens"
    rendered = root / name
    if not (rendered / "rig.yaml").exists():
        cfg = preset("front-left").with_overrides(frames=args.frames, seed=args.seed, height=128, width=416)
        lens = Distortion("opencv", LENS)
        cfg = replace(cfg, cameras=[replace(c, distortion=lens) for c in cfg.cameras])
        partial = rendered.with_name(name + ".partial")
        shutil.rmtree(partial, ignore_errors=True)
        render_sequence(cfg, partial, workers=2)
        partial.rename(rendered)
    drive = write_extract(rendered, root / "kitti_extract")
    doc = {"seed": args.seed, "frames": args.frames, "lens": LENS, "dropped": DROPPED, "late_s": LATE,
           "oxts_gap_s": OXTS_GAP, "runs": {}}  # fmt: skip
    for mode, bundle_adjust in (("online", False), ("default", True)):
        result = calibrate(drive, root / "kitti_extract" / f"{mode}.json", bundle_adjust)
        errors = result.get("ground_truth_errors") or []
        doc["runs"][mode] = {"errors": errors, "warnings": result.get("warnings", []),
                             "sources": [e.get("source") for e in result["extrinsics"]]}  # fmt: skip
        for e in errors:
            print(
                f"{mode}: rotation {e.get('rotation_error_deg')}, direction {e.get('translation_direction_error_deg')}, "
                f"translation / baseline {e.get('translation_error_rel_baseline')}"
            )
    write_json(args.out, doc)


if __name__ == "__main__":
    main()
