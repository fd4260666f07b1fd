"""Benchmark of ego-motion training and inference: training snippets (and images) per second, pose-net and
depth-net frames per second, at the default resolution, on CPU (and CUDA when available).

    python bench/bench_train.py [--size small] [--height 64 --width 208] [--batch 4] [--steps 10] [--threads 1,2] [--devices cpu,cuda]

Training: a full step (depth of every frame, pose of every source, the loss, backward, Adam) on random 3-frame
snippets: the 4-scale loss with and without the geometry-consistency loss, and the shipped recipe (one scale, the
motions refined by Gauss-Newton photometric alignment for the depth's loss, the pose net pulled towards them); a
training image is a target frame.
The compiled case runs the step through ``torch.compile`` as ``model.compile`` does; its first step (the
compilation: minutes on two cores without inductor's on-disk cache, half a minute with it) is reported apart.
Inference: ``model.pose`` on (target, source) pairs and ``model.depth`` on frames, batch 16, no gradients.
Also times the 3x3 box SSIM of :mod:`ocalib.losses.photometric` against kornia's ``ssim_loss`` (forward +
backward). Medians over the repeats. Prints a table and writes ``bench/results/train.json``.
"""

from __future__ import annotations

import argparse
import statistics
import time

import kornia
import torch
from common import write_json
from ocalib.train.module import EgoMotionModule

from ocalib.losses import ssim_error
from ocalib.models import EgoMotionModel


def timed(fn, repeats: int, device: str) -> float:
    """Median seconds of ``fn()`` over ``repeats`` runs after one warm-up."""
    fn()
    times = []
    for _ in range(repeats):
        if device.startswith("cuda"):
            torch.cuda.synchronize()
        t0 = time.perf_counter()
        fn()
        if device.startswith("cuda"):
            torch.cuda.synchronize()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def snippet_batch(batch: int, height: int, width: int, device: str) -> dict:
    K = torch.tensor([[0.58 * width, 0, width / 2 - 0.5], [0, 1.92 * height, height / 2 - 0.5], [0, 0, 1]])
    return {"image": torch.rand(batch, 3, 3, height, width, device=device), "K": K.expand(batch, 3, 3).to(device)}


TRAINING_CASES = {  # label -> EgoMotionModule options
    "SC loss, 4 scales": dict(geometry=0.1),
    "no SC, 4 scales": dict(geometry=0.0),
    "shipped recipe (1 scale, align 3+3, distill)": dict(
        geometry=0.0, scales=1, automask=False, align=(3, 3), distill=0.1
    ),
    "shipped recipe, compiled (model.compile)": dict(
        geometry=0.0, scales=1, automask=False, align=(3, 3), distill=0.1, compile=True
    ),
}


def bench_training(size, height, width, batch, steps, label, device) -> dict:
    module = EgoMotionModule(size=size, height=height, width=width, **TRAINING_CASES[label]).to(device)
    optimizer = torch.optim.Adam(module.parameters(), lr=1e-4)
    data = snippet_batch(batch, height, width, device)
    forward = module.compiled_step() if module.hparams.compile else module.step

    def step():
        out, _, _ = forward(data)
        optimizer.zero_grad()
        out.total.backward()
        optimizer.step()

    t0 = time.perf_counter()
    step()  # compiles, when compiled
    first = time.perf_counter() - t0
    seconds = timed(step, steps, device)
    return {
        "case": f"train step, {label}",
        "batch": batch,
        "ms": seconds * 1e3,
        "first_step_s": first,
        "snippets_per_s": batch / seconds,
        "images_per_s": batch / seconds,
    }


def bench_inference(size, height, width, repeats, device) -> list[dict]:
    model = EgoMotionModel(size, height, width).to(device).eval()
    frames = torch.rand(16, 3, height, width, device=device)
    rows = []
    with torch.inference_mode():
        s = timed(lambda: model.pose(frames, frames.roll(1, 0)), repeats, device)
        rows.append({"case": "pose net (pairs)", "batch": 16, "ms": s * 1e3, "frames_per_s": 16 / s})
        s = timed(lambda: model.depth(frames), repeats, device)
        rows.append({"case": "depth net", "batch": 16, "ms": s * 1e3, "frames_per_s": 16 / s})
    return rows


def bench_ssim(height, width, repeats, device) -> list[dict]:
    x0, y = torch.rand(2, 8, 3, height, width, device=device)
    rows = []
    for name, fn in [
        ("ssim box 3x3 (ocalib)", lambda x: ssim_error(x, y)),
        ("ssim kornia ssim_loss window 3", lambda x: kornia.losses.ssim_loss(x, y, 3, reduction="none")),
    ]:
        x = x0.clone().requires_grad_()
        s = timed(lambda: fn(x).sum().backward(), repeats, device)
        rows.append({"case": name, "batch": 8, "ms": s * 1e3})
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", default="small")
    p.add_argument("--height", type=int, default=64)
    p.add_argument("--width", type=int, default=208)
    p.add_argument("--batch", type=int, default=4)
    p.add_argument("--steps", type=int, default=10)
    p.add_argument("--threads", default="1,2", help="torch intra-op thread counts to try")
    p.add_argument("--devices", default="cpu,cuda", help="devices to time (cuda only when available)")
    p.add_argument("--out", default="bench/results/train.json")
    args = p.parse_args(argv)
    devices = [d for d in args.devices.split(",") if d != "cuda" or torch.cuda.is_available()]
    rows = []
    for threads in [int(t) for t in args.threads.split(",")]:
        torch.set_num_threads(threads)
        for device in devices:
            torch.manual_seed(0)
            part = []
            for label in TRAINING_CASES:
                part.append(bench_training(args.size, args.height, args.width, args.batch, args.steps, label, device))
            part += bench_inference(args.size, args.height, args.width, args.steps, device)
            part += bench_ssim(args.height, args.width, args.steps, device)
            rows += [{**r, "device": device, "threads": threads} for r in part]
    print(f"{args.size} model, {args.height}x{args.width} (median of {args.steps})")
    print(f"{'case':<56} {'device':>6} {'threads':>7} {'batch':>5} {'ms':>8} {'per second':>15} {'first step s':>12}")
    for r in rows:
        rate = r.get("snippets_per_s") or r.get("frames_per_s")
        unit = "snippets" if "snippets_per_s" in r else "frames" if rate else ""
        text = f"{rate:.1f} {unit}" if rate else ""
        first = f"{r['first_step_s']:.1f}" if "first_step_s" in r else ""
        print(
            f"{r['case']:<56} {r['device']:>6} {r['threads']:>7} {r['batch']:>5} {r['ms']:>8.1f} {text:>15} {first:>12}"
        )
    write_json(
        args.out,
        {
            "benchmark": "ego-motion training",
            "size": args.size,
            "height": args.height,
            "width": args.width,
            "results": [{k: round(v, 2) if isinstance(v, float) else v for k, v in r.items()} for r in rows],
        },
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
