"""Benchmark of the training data loader: milliseconds a batch of snippets, with and without the decoded-frame
cache (``data.cache_mb``), on the default config's training data (the synthetic presets at 64x208, rendered into
``--root`` on first use) and its augmentation.

    python bench/bench_loader.py [--root data/synth] [--cache-mb 0,512] [--batches 300]

One process, one thread (the loader's worker runs beside the training step's threads). For each cache size: one
full epoch (the cache fills; its mean is reported), then the median over ``--batches`` batches of the next epoch.
Prints a table and writes ``bench/results/loader.json``.
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch
from common import write_json
from ocalib.train.synthetic import SyntheticDataModule

PRESETS = {
    "handheld": [0, 1, 8, 9],
    "front-left": [2, 3, 10, 11],
    "front-rear": [4, 5, 12, 13],
    "stereo": [6, 7, 14, 15],
}


def batch_times(loader, limit: int | None = None) -> list[float]:
    """Seconds of each batch of one pass over ``loader`` (the first ``limit`` batches)."""
    times, t0 = [], time.perf_counter()
    for _ in loader:
        t1 = time.perf_counter()
        times.append(t1 - t0)
        t0 = t1
        if limit is not None and len(times) == limit:
            break
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--root", default="data/synth")
    parser.add_argument("--cache-mb", default="0,512", help="comma-separated cache sizes in MB")
    parser.add_argument("--batches", type=int, default=300)
    parser.add_argument("--batch-size", type=int, default=4)
    parser.add_argument("--out", default="bench/results/loader.json")
    args = parser.parse_args()
    torch.set_num_threads(1)
    rows = []
    for cache_mb in (float(c) for c in args.cache_mb.split(",")):
        dm = SyntheticDataModule(
            presets=PRESETS, val_presets=None, root=args.root, batch_size=args.batch_size, cache_mb=cache_mb
        )
        dm.prepare_data()
        dm.setup("fit")
        loader = dm.train_dataloader()
        first = batch_times(loader)
        then = batch_times(loader, args.batches)
        cache = dm.train_set.cache
        rows.append(
            {
                "cache_mb": cache_mb,
                "first_epoch_mean_ms": 1e3 * statistics.mean(first),
                "median_ms": 1e3 * statistics.median(then),
                "batches": len(then),
                "cached_frames": len(cache),
                "cached_mb": cache.nbytes / 2**20,
            }
        )
    print(f"training loader, batch {args.batch_size}, 1 thread (median of {args.batches} batches after one epoch)")
    print(f"{'cache MB':>8} {'first epoch ms':>14} {'then ms':>8} {'cached frames':>13} {'cached MB':>9}")
    for r in rows:
        print(
            f"{r['cache_mb']:>8g} {r['first_epoch_mean_ms']:>14.1f} {r['median_ms']:>8.1f} {r['cached_frames']:>13} "
            f"{r['cached_mb']:>9.0f}"
        )
    base = rows[0]["median_ms"]
    for r in rows[1:]:
        print(
            f"cache {r['cache_mb']:g} MB: {base / r['median_ms']:.2f}x the batches a second of {rows[0]['cache_mb']:g} MB"
        )
    write_json(args.out, {"benchmark": "training data loader", "batch_size": args.batch_size, "rows": rows})


if __name__ == "__main__":
    main()
