"""The metric trajectory as priors in the rig bundle adjustment against a Sim(3) fit to it, side by side.

For each held-out rig (rendered when missing), ``ocalib calibrate``'s on-line pass (network front end) once, then
the rig bundle adjustment twice on the same workspace settings, COLMAP on one thread (so the two differ by the prior
alone): with the sequence's camera-0 poses scaled onto the reconstruction by a Sim(3) fit (the default), and as
position priors with the stated noise (``--metric-noise``, metres; the renderer's poses are exact). Reports the
bundle adjustment's rotation error (deg), translation direction error (deg; in the ground plane on cars) and
translation error over the baseline, whether it was trusted, and its seconds.

    python bench/bench_metric_prior.py [--sequences handheld-1001 front-left-1008 ...] [--metric-noise 0.001]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from bench_calibnet_accuracy import ensure
from bench_rigba import errors_row
from common import add_sequence_arguments, write_json

from ocalib.calibnet.bundle import refine_calibration
from ocalib.calibnet.run import calibrate_images
from ocalib.frontend import FrontEndOptions
from ocalib.rigba.options import BundleOptions, FeatureOptions, MapperOptions

KEYS = ("rotation_deg", "direction_deg", "translation_rel_baseline")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_sequence_arguments(p, ["handheld-1001", "front-left-1008", "handheld-2001", "front-left-2002"])
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--metric-noise", type=float, default=0.001, help="the priors' noise, metres per axis")
    p.add_argument("--out", default="bench/results/metric_prior.json")
    args = p.parse_args()
    results = {}
    print(f"{'sequence':18} {'Sim(3) fit (rot/dir/t)':>24} {'priors (rot/dir/t)':>24}")
    for name in args.sequences:
        path = ensure(Path(args.root), name, args.frames)
        result = calibrate_images(path, frontend=FrontEndOptions("network"), max_frames=args.frames, progress=False)
        metric = result.sequence.cameras[0].poses
        rows = results[Path(path).name] = {}
        for tag, noise in (("sim3", None), ("prior", args.metric_noise)):
            options = BundleOptions(FeatureOptions(threads=1), MapperOptions(threads=1, metric_noise=noise))
            start = time.perf_counter()
            refine_calibration(result, metric, options, progress=False)
            rows[tag] = errors_row(result.bundle_errors[0]) | {
                "trusted": bool(result.bundle.trusted[1]), "seconds": time.perf_counter() - start}  # fmt: skip
        cells = ["/".join(f"{rows[t][k]:.2f}" for k in KEYS) for t in ("sim3", "prior")]
        print(f"{Path(path).name:18} {cells[0]:>24} {cells[1]:>24}", flush=True)
        write_json(args.out, {"frames": args.frames, "metric_noise": args.metric_noise, "results": results})


if __name__ == "__main__":
    main()
