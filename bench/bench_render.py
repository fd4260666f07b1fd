"""Benchmark of the synthetic renderer: rendered frames per second per camera.

    python bench/bench_render.py [--sizes 128x416,256x832] [--threads 1,2] [--frames 8] [--repeats 3]

Renders ``--frames`` frames of every camera of a preset, ``--repeats`` times, per image size and torch
thread count, and reports the median time per view (one camera, one frame; PNG writing excluded).
Prints a table and writes ``bench/results/render.json``.
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch
from common import write_json

from ocalib.synth import preset
from ocalib.synth.render import WorldTensors, render_view
from ocalib.synth.sequence import camera_poses, world_for


def bench(name: str, height: int, width: int, frames: int, repeats: int, device: str) -> dict:
    cfg = preset(name).with_overrides(frames=frames + 1, height=height, width=width)
    poses = camera_poses(cfg)
    t0 = time.perf_counter()
    world = WorldTensors.from_world(world_for(cfg, poses), device)
    world_s = time.perf_counter() - t0
    Ks = [c.K(height, width) for c in cfg.cameras]
    render_view(world, Ks[0], poses[0, 0], height, width, cfg.supersample)  # warm-up
    per_view = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for n in range(1, frames + 1):
            for k, K in enumerate(Ks):
                render_view(world, K, poses[k, n], height, width, cfg.supersample)
        if device.startswith("cuda"):
            torch.cuda.synchronize()
        per_view.append((time.perf_counter() - t0) / (frames * len(Ks)))
    med = statistics.median(per_view)
    return {
        "preset": name,
        "height": height,
        "width": width,
        "threads": torch.get_num_threads(),
        "device": device,
        "boxes": len(world.boxes),
        "world_build_s": round(world_s, 3),
        "ms_per_view_median": round(med * 1000, 2),
        "ms_per_view_all": [round(v * 1000, 2) for v in per_view],
        "fps_per_camera_median": round(1 / med, 2),
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--preset", default="front-rear")
    p.add_argument("--sizes", default="128x416,256x832")
    p.add_argument("--threads", default="1,2", help="torch intra-op thread counts to try")
    p.add_argument("--frames", type=int, default=8)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--device", default="cpu")
    p.add_argument("--out", default="bench/results/render.json")
    args = p.parse_args(argv)
    rows = []
    with torch.inference_mode():
        for threads in [int(t) for t in args.threads.split(",")]:
            torch.set_num_threads(threads)
            for size in args.sizes.split(","):
                h, w = (int(x) for x in size.lower().split("x"))
                rows.append(bench(args.preset, h, w, args.frames, args.repeats, args.device))
    print(f"{'size':>9} {'threads':>7} {'ms/view':>8} {'fps/camera':>10}   (median of {args.repeats}; {args.preset})")
    for r in rows:
        print(
            f"{r['height']}x{r['width']:<5} {r['threads']:>7} {r['ms_per_view_median']:>8.1f} {r['fps_per_camera_median']:>10.1f}"
        )
    write_json(args.out, {"benchmark": "synth render", "results": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
