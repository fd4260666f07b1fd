"""The rig bundle adjustment on held-out rendered rigs: accuracy beside the on-line head's, wall time, peak memory.

For each sequence (rendered by ``ocalib synth`` with a held-out seed when missing) and each front end, runs
``ocalib calibrate``'s on-line pass and then the stage with the sequence's camera-0 poses as the metric trajectory.
Reports the head's and the bundle adjustment's rotation error, translation direction error (with the unobservable
direction projected out: in the ground plane on cars) and translation error over the baseline in metres; the stage's
wall time, its peak memory above the process's resident size before it, and its share of calibrate's time. Prints a
table, writes JSON.

    python bench/bench_rigba.py [--sequences front-left-1002 handheld-1001 ...] [--frontends network opencv]
    python bench/bench_rigba.py --sequences front-left-1002 --frontends opencv --every 50 --out bench/results/rigba_stream.json

``--every N``: the streaming variant (a run after every N frames, features and matches kept); each run's seconds
and the stage's cost a frame are reported.
"""

from __future__ import annotations

import argparse
import threading
import time
from pathlib import Path

import numpy as np
import torch
from bench_calibnet_accuracy import ensure
from common import add_sequence_arguments, write_json

from ocalib.calibnet.bundle import refine_calibration
from ocalib.calibnet.run import calibrate_images
from ocalib.calibnet.sequence import open_calibration_sequence
from ocalib.frontend import FRONTENDS, FrontEndOptions
from ocalib.rigba.online import OnlineRigOptions
from ocalib.rigba.options import BundleOptions, FeatureOptions, MapperOptions
from ocalib.rigba.stream import OnlineRigStage

DEFAULT = ["handheld-1001", "front-left-1008", "handheld-1007", "front-left-2002", "handheld-2001", "front-left-1002"]


def rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


class PeakMemory:
    """The peak resident size above the size at entry, sampled every 50 ms (COLMAP's memory is not Python's)."""

    def __enter__(self):
        self.base, self.peak, self._stop = rss_mb(), 0.0, threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)
        self._thread.start()
        return self

    def _sample(self):
        while not self._stop.wait(0.05):
            self.peak = max(self.peak, rss_mb() - self.base)

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()


def errors_row(e: dict) -> dict:
    return {
        "rotation_deg": e["rotation_error_deg"],
        "direction_deg": e["translation_direction_error_deg"],
        "translation_rel_baseline": e.get("translation_error_rel_baseline"),
        "in_plane": e["compared_in_plane"],
        "height_m": e.get("height_error"),  # along the ground's normal on a car (outside its targets)
    }


def run(path: Path, frontend: str, frames: int, options: BundleOptions, every: int | None, time_offset=None,
        online_rig: bool = False) -> dict:  # fmt: skip
    """``ocalib calibrate``'s on-line pass (with the on-line rig estimator where ``online_rig``) and the bundle
    adjustment, camera 0's rendered poses the metric trajectory."""
    start = time.perf_counter()
    sequence = open_calibration_sequence(path, max_frames=frames, time_offset=time_offset,
                                         frontend=FrontEndOptions(frontend))  # fmt: skip
    metric = sequence.cameras[0].poses[:frames]
    rig = OnlineRigStage(sequence, metric, OnlineRigOptions(metric_noise=0.0)) if online_rig else None  # exact: held
    result = calibrate_images(sequence, frontend=FrontEndOptions(frontend), max_frames=frames, progress=False,
                              on_frame=rig)  # fmt: skip
    if rig is not None:
        rig.attach(result)
    online = time.perf_counter() - start
    with PeakMemory() as memory:
        start = time.perf_counter()
        refine_calibration(result, metric, options, every=every, progress=False)
        stage = time.perf_counter() - start
    b = result.bundle
    names = sequence.names[1:]
    rig_errors = result.rig_errors or [None] * len(names)
    return {
        "head": errors_row(result.errors[0]),
        "rig_estimator": None if result.rig_errors is None else errors_row(result.rig_errors[0]),
        "bundle": errors_row(result.bundle_errors[0]),
        "trusted": bool(b.trusted[1]),
        "cameras": {  # every camera k >= 1 (the rows above are camera 1's)
            name: {
                "head": errors_row(h),
                "rig_estimator": None if r is None else errors_row(r),
                "bundle": errors_row(e),
                "trusted": bool(t),
            }
            for name, h, r, e, t in zip(names, result.errors, rig_errors, result.bundle_errors, b.trusted[1:])
        },  # fmt: skip
        "extrinsics": {  # T_cam0_camk, camera 0's first: the batch adjustment's (its units), the estimator's (metres)
            "bundle": b.extrinsics.tolist(),
            "rig_estimator": None if rig is None or rig.final is None else rig.final.extrinsics.tolist(),
        },
        "warnings": b.warnings,
        "online_seconds": online,
        "stage_seconds": stage,
        "stage_share": stage / (online + stage),
        "stage_peak_mb": memory.peak,
        "stage_seconds_per_frame": stage / frames,
        "stats": b.stats,
        "time_offsets": None if result.sequence.pairing is None else result.sequence.pairing.offsets.tolist(),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_sequence_arguments(p, DEFAULT)
    p.add_argument("--frontends", nargs="+", choices=FRONTENDS, default=list(FRONTENDS))
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--keyframe-step", type=int, default=BundleOptions().keyframe_step)
    p.add_argument("--peak-threshold", type=float, default=FeatureOptions().peak_threshold, help="SIFT's")
    p.add_argument("--overlap", type=int, default=FeatureOptions().overlap, help="frames each frame is matched to")
    p.add_argument("--threads", type=int, default=-1, help="COLMAP's threads (-1: all)")
    p.add_argument("--every", type=int, help="the streaming variant: a run after every N frames")
    p.add_argument(
        "--online-rig",
        action="store_true",
        help="run the on-line rig estimator in the on-line pass too (the rendered poses held: exact)",
    )
    p.add_argument("--metric-noise", type=float, help="calibrate's: the metric trajectory inside the adjustment")
    p.add_argument("--out", default="bench/results/rigba.json")
    args = p.parse_args()
    torch.set_num_threads(2)
    features = FeatureOptions(peak_threshold=args.peak_threshold, overlap=args.overlap, threads=args.threads)
    mapper = MapperOptions(threads=args.threads, metric_noise=args.metric_noise)
    options = BundleOptions(features, mapper, keyframe_step=args.keyframe_step)
    results = {}
    header = (
        f"{'sequence':16} {'front end':9} {'head rot/dir/t':>22} {'+ BA rot/dir/t':>22} {'BA s':>6} "
        f"{'share':>6} {'MB':>6}"
    )
    print(header)
    for name in args.sequences:
        path = ensure(Path(args.root), name, args.frames)
        for frontend in args.frontends:
            r = results.setdefault(path.name, {})[frontend] = run(
                path, frontend, args.frames, options, args.every, online_rig=args.online_rig
            )
            cell = lambda e: (
                f"{e['rotation_deg']:6.2f} {e['direction_deg']:6.1f} "  # noqa: E731
                f"{np.nan if e['translation_rel_baseline'] is None else e['translation_rel_baseline']:6.2f}"
            )
            print(
                f"{path.name:16} {frontend:9} {cell(r['head']):>22} {cell(r['bundle']):>22} "
                f"{r['stage_seconds']:6.1f} {r['stage_share']:6.0%} {r['stage_peak_mb']:6.0f}"
                + ("" if r["trusted"] else "  (BA not trusted: head kept)"),
                flush=True,
            )
            for x in r["stats"].get("stream", []):
                print(f"    run at frame {x['frame']:4d}: {x['seconds']:6.1f} s")
            doc = {"frames": args.frames, "keyframe_step": args.keyframe_step, "every": args.every,
                   "peak_threshold": args.peak_threshold, "overlap": args.overlap, "metric_noise": args.metric_noise,
                   "results": results}  # fmt: skip
            write_json(args.out, doc)  # after every row: an interrupted run keeps what it measured


if __name__ == "__main__":
    main()
