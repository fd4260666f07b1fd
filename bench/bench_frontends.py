"""Every front end's frame-to-frame motion on sequences with ground truth, real or rendered, against the baselines a
front end must beat (predicting no rotation, and a fixed forward translation), and the front end that ``calibrate
--frontend auto`` (the default) keeps on each rig.

    python bench/bench_frontends.py --sequences data/real/kitti00/sequences/00 [--cameras image_0]
        [--frontends network opencv] [--checkpoints NAME=FILE ...] [--frames 200] [--crop-rig] [--out JSON]
    python bench/bench_frontends.py --sequences handheld-1001 front-left-1002 ... --frames 100

A sequence: any supported layout with ground-truth poses, e.g. a KITTI odometry download's ``sequences/00``
(``image_0``, ``calib.txt``, ``times.txt``, ``poses/00.txt`` beside ``sequences``). ``--crop-rig``: instead, a real
rig made of two overlapping crops (left and right, two thirds of the width each) of the first camera, written
under ``data/real/`` (the rig layout, the camera's poses; its extrinsic is the identity).

Per camera and front end (each of :data:`ocalib.frontend.FRONTENDS` as ``calibrate`` makes it, defaults; each
``--checkpoints`` entry as the network front end with that model): the median frame-to-frame rotation error (deg),
the median translation direction error (deg, frames that move), the rotation gain about each camera axis (1 is
unbiased; below 1 the front end under-reports rotation), the frames it lost its tracks on (the OpenCV front end's)
and the frames a second. With two cameras or more (a real rig, e.g. two crops of one camera: its extrinsic the
identity), each front end's congruence residual over the first ``AUTO_FRAMES`` frames, which ``calibrate --frontend
auto`` (the default) ranks the front ends by, and the one it keeps. Prints a table, writes the JSON.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np
import torch
import yaml
from bench_calibnet_accuracy import ensure
from common import add_sequence_arguments, shown_path, write_json
from tqdm import tqdm

from ocalib.data import open_sequence
from ocalib.eval.pose_metrics import congruence_residual, frame_errors, frame_motions, rotation_gain
from ocalib.frontend import AUTO_FRAMES, FRONTENDS, FrontEndOptions, build_frontend
from ocalib.io.poses import write_kitti


def trajectories(sequence, options: FrontEndOptions, frames: int) -> tuple[np.ndarray, float, dict]:
    """Every camera's trajectory (T, C, 4, 4) from the front end of ``options``, its frames a second, and what it
    reports of the stream (e.g. the OpenCV front end's frames lost per camera)."""
    front_end = build_frontend(sequence, options)
    data = front_end.frames(sequence)
    C = len(sequence.cameras)
    pose, out = torch.eye(4, dtype=torch.float64).expand(1, C, 4, 4), []
    rig = torch.eye(3, dtype=torch.float64).expand(1, C - 1, 3, 3)
    start = time.perf_counter()
    with torch.inference_mode():
        for t in tqdm(range(frames), desc=options.name if options.checkpoint is None else options.checkpoint):
            pose = pose @ front_end(data[t], rig)
            out.append(pose[0].clone())
    fps = frames / (time.perf_counter() - start)
    return torch.stack(out).numpy(), fps, front_end.report(sequence.names, frames, None)[0]


def crop_rig(sequence, frames: int, root: Path = Path("data/real")) -> Path:
    """A rig folder of two overlapping crops (left, right) of ``sequence``'s first camera's first ``frames``; their
    extrinsic is the identity (one centre, one orientation)."""
    cam = sequence.cameras[0]
    H, W = cam.size
    width = 2 * W // 3
    out = root / f"{sequence.path.name}-{cam.name}-crops"
    specs = []
    for name, x0 in (("left", 0), ("right", W - width)):
        (out / name / "images").mkdir(parents=True, exist_ok=True)
        for t, path in enumerate(cam.images[:frames]):
            cv2.imwrite(str(out / name / "images" / f"{t:06d}.png"), cv2.imread(str(path))[:, x0 : x0 + width])
        write_kitti(out / name / "poses.txt", cam.poses[:frames])
        K = cam.K.copy()
        K[0, 2] -= x0
        specs.append({"name": name, "width": width, "height": H, "K": K.tolist(), "T_cam0_cam": np.eye(4).tolist()})
    (out / "rig.yaml").write_text(yaml.safe_dump({"cameras": specs}))
    return out


def errors(pred: np.ndarray, gt: np.ndarray) -> dict:
    """Median rotation and direction errors and the rotation gain of trajectory ``pred`` (T, 4, 4) against ``gt``."""
    e = frame_errors(pred, gt)
    gain = rotation_gain(frame_motions(pred), frame_motions(gt))
    return {
        "rotation_deg": float(np.median(e["rotation_deg"])),
        "direction_deg": float(np.nanmedian(e["direction_deg"])),
        "gain_xyz": [float(g) for g in gain],
    }


def baselines(gt: np.ndarray) -> dict:
    """The :func:`errors` of predicting no rotation and a translation straight ahead (+z) every frame."""
    forward = np.tile(np.eye(4), (len(gt), 1, 1))
    forward[:, 2, 3] = np.arange(len(gt), dtype=np.float64)
    return errors(forward, gt)


def measure(sequence, runs: dict[str, FrontEndOptions], frames: int) -> dict:
    """Per front end of ``runs`` (label -> options): each camera's :func:`errors`, the frames a second and, with two
    cameras or more, the congruence residual over the first ``AUTO_FRAMES``; the baselines; the front end
    ``--frontend auto`` keeps."""
    rows = {}
    for label, options in runs.items():
        traj, fps, report = trajectories(sequence, options, frames)
        rows[label] = {cam.name: errors(traj[:, c], cam.poses[:frames]) for c, cam in enumerate(sequence.cameras)}
        for name, lost in report.get("lost_frames", {}).items():
            rows[label][name]["lost_frames"] = lost
        rows[label]["frames_per_second"] = fps
        if len(sequence.cameras) > 1 and label in FRONTENDS:
            rows[label]["congruence_residual"] = congruence_residual(traj[:AUTO_FRAMES])
    rows["baselines"] = {cam.name: baselines(cam.poses[:frames]) for cam in sequence.cameras}
    doc = {"frames": frames, "results": rows}
    residuals = {label: row["congruence_residual"] for label, row in rows.items() if "congruence_residual" in row}
    if residuals:
        doc["auto_choice"] = min(residuals, key=lambda label: (np.isnan(residuals[label]), residuals[label]))
    return doc


def table(name: str, doc: dict, cameras: list[str]) -> None:
    """Print ``doc`` (:func:`measure`'s) as a markdown table."""
    print(f"\n{name}, {doc['frames']} frames: median frame-to-frame errors\n")
    print("| front end | camera | rotation deg | direction deg | rotation gain x / y / z | frames lost | frames/s |")
    print("|---|---|---|---|---|---|---|")
    for label, row in doc["results"].items():
        for cam in cameras:
            cells = row[cam]
            shown = "no rotation; forward" if label == "baselines" else label
            fps = f"{row['frames_per_second']:.1f}" if "frames_per_second" in row else ""
            gain = " / ".join(f"{g:.2f}" for g in cells["gain_xyz"])
            lost = cells.get("lost_frames", "")
            print(
                f"| {shown} | {cam} | {cells['rotation_deg']:.3f} | {cells['direction_deg']:.2f} | {gain} | {lost} | {fps} |"
            )
    if "auto_choice" in doc:
        tried = ", ".join(f"{k} {r['congruence_residual']:.3f}" for k, r in doc["results"].items()
                          if "congruence_residual" in r)  # fmt: skip
        print(f"\ncongruence residual over the first {AUTO_FRAMES} frames: {tried}; auto keeps {doc['auto_choice']}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_sequence_arguments(p, ["data/real/kitti00/sequences/00"])
    p.add_argument("--cameras", nargs="+")
    p.add_argument("--frontends", nargs="+", default=list(FRONTENDS), choices=list(FRONTENDS))
    p.add_argument("--checkpoints", nargs="*", default=[], metavar="NAME=FILE", help="more network models")
    p.add_argument("--frames", type=int, default=200)
    p.add_argument("--crop-rig", action="store_true", help="a rig of two crops of the first camera instead")
    p.add_argument("--out", default="bench/results/frontends.json")
    args = p.parse_args()

    runs = {name: FrontEndOptions(name) for name in args.frontends}
    for entry in args.checkpoints:
        name, _, path = entry.partition("=")
        runs[name] = FrontEndOptions("network", checkpoint=path)
    results = {}
    for name in args.sequences:
        path = Path(name) if Path(name).is_dir() else ensure(Path(args.root), name, max(args.frames, 300))
        sequence = open_sequence(path)
        if args.cameras:
            sequence = sequence.select(args.cameras)
        frames = min(args.frames, len(sequence))
        if args.crop_rig:
            sequence = open_sequence(crop_rig(sequence, frames))
        label = sequence.path.name
        results[label] = measure(sequence, runs, frames) | {"crop_rig": args.crop_rig}
        table(label, results[label], sequence.names)
    write_json(args.out, {"sequences": [shown_path(n) if Path(n).is_dir() else n for n in args.sequences],
                          "results": results})  # fmt: skip


if __name__ == "__main__":
    main()
