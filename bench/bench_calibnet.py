"""Per-frame latency of the on-line calibration net (pose network + head on one graph), and its parts.

Measures, side by side in one run, the median wall time per frame of: the whole graph
(:class:`OnlineCalibrationNet`) without and with photometric alignment (``align``, the default of
``ocalib calibrate``; with and without ``rig_align``), the pose network alone on the same (previous, current) batch, and the head alone, for a
rig of C cameras at the model's resolution, on a rendered handheld sequence; frames per second follow. CPU always; CUDA
when available. Prints a table and writes ``bench/results/calibnet.json``.

    python bench/bench_calibnet.py [--checkpoint CKPT] [--cameras 2] [--frames 60] [--threads 2] [--devices cpu,cuda]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import torch
from common import write_json

from ocalib.calib.drivers.online import OnlineCalibrator
from ocalib.calibnet import OnlineCalibrationNet
from ocalib.frontend.network import NetworkFrontEnd
from ocalib.models import EgoMotionModel, load_model
from ocalib.synth import preset, render_rig


def timed(fn, frames: int, device: torch.device) -> list[float]:
    """Wall seconds of each of ``frames`` calls of fn(t), synchronising CUDA around each."""
    out = []
    for t in range(frames):
        if device.type == "cuda":
            torch.cuda.synchronize()
        start = time.perf_counter()
        fn(t)
        if device.type == "cuda":
            torch.cuda.synchronize()
        out.append(time.perf_counter() - start)
    return out


def bench(model: EgoMotionModel, device: torch.device, cameras: int, frames: int, warmup: int = 5) -> dict:
    model = model.to(device).eval()
    H, W = model.height, model.width
    seq = render_rig(preset("handheld").with_overrides(frames=frames + warmup, height=H, width=W, seed=1001))
    pick = [c % seq.images.shape[0] for c in range(cameras)]  # the rig's cameras, repeated for C > 2
    images = seq.images[pick].transpose(0, 1).to(device)  # (T, C, 3, H, W)
    K = torch.from_numpy(np.stack([seq.rig.cameras[c].K for c in pick])).float()
    graph = lambda **options: OnlineCalibrationNet(  # noqa: E731
        NetworkFrontEnd(model, cameras, **options), OnlineCalibrator(cameras)
    ).to(device)
    net, aligned = graph(), graph(intrinsics=K, align=True)
    camera_only = graph(intrinsics=K, align=True, rig_align=False)
    head = OnlineCalibrator(cameras, device=device)
    poses = torch.eye(4, dtype=torch.float64, device=device).repeat(frames + warmup, cameras, 1, 1)
    poses[:, :, :3, 3] = torch.randn(frames + warmup, cameras, 3, dtype=torch.float64, device=device).cumsum(0)
    with torch.inference_mode():
        cases = {
            "whole graph": lambda t: net(images[t]),
            "aligned graph": lambda t: aligned(images[t]),
            "aligned graph, no rig": lambda t: camera_only(images[t]),
            "pose network": lambda t: model.pose(images[t - 1], images[t]),
            "head": lambda t: head(poses[t]),
        }
        result = {}
        for name, fn in cases.items():
            timed(fn, warmup, device)
            times = timed(lambda t: fn(t + warmup), frames, device)
            result[name] = {"median_ms": 1e3 * statistics.median(times), "fps": 1 / statistics.median(times)}
    return {"device": str(device), "cameras": cameras, "resolution": [H, W], "frames": frames, "cases": result}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--checkpoint", help="model file (default: the shipped one, else an untrained small model)")
    p.add_argument("--cameras", type=int, default=2)
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--devices", default="cpu,cuda", help="devices to time (cuda only when available)")
    p.add_argument("--out", default="bench/results/calibnet.json")
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    try:
        model = load_model(args.checkpoint)
    except Exception:  # noqa: BLE001 - no shipped checkpoint yet: the timing does not depend on the weights
        if args.checkpoint:
            raise
        model = EgoMotionModel("small")
    devices = [torch.device(d) for d in args.devices.split(",") if d != "cuda" or torch.cuda.is_available()]
    runs = [bench(model, d, args.cameras, args.frames) for d in devices]
    print(
        f"on-line calibration net, {args.cameras} cameras, model {model.size} at {model.height}x{model.width}, "
        f"{args.threads} CPU threads, median of {args.frames} frames"
    )
    print(f"{'device':8} {'case':14} {'ms/frame':>10} {'frames/s':>10}")
    for r in runs:
        for name, c in r["cases"].items():
            print(f"{r['device']:8} {name:14} {c['median_ms']:10.2f} {c['fps']:10.1f}")
    write_json(args.out, {"threads": args.threads, "model": model.size, "runs": runs})


if __name__ == "__main__":
    main()
