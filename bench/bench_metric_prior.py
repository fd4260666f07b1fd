"""Camera 0's metric trajectory inside the rig bundle adjustment against a Sim(3) fit to it, side by side.

For each held-out rig (rendered when missing) and front end, ``ocalib calibrate``'s on-line pass once (with the on-line
rig estimator, which holds the metric trajectory fixed in its window), then the rig bundle adjustment once per variant
on the same workspace settings, COLMAP on one thread (so that they differ by the trajectory's use alone): ``sim3``, the
reconstruction scaled onto the sequence's camera-0 poses by a Sim(3) fit; ``prior``, their positions as priors with the
stated noise (``--metric-noise``, metres; the renderer's poses are exact); ``held``, every rig frame held at them
(``metric_noise`` 0). Reports each one's rotation error (deg), translation direction error (deg; in the ground plane on
cars) and translation error over the baseline, whether the adjustment was trusted, and its seconds.

    python bench/bench_metric_prior.py [--sequences handheld-1001 front-left-1008 ...] [--frontends network opencv]
        [--variants sim3 prior held] [--trajectory-noise METRES DEG]

``--trajectory-noise``: the estimator and the adjustments get the trajectory with that noise on every pose.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from bench_calibnet_accuracy import ensure
from bench_rigba import errors_row
from common import add_sequence_arguments, write_json
from scipy.spatial.transform import Rotation

from ocalib.calibnet.bundle import refine_calibration
from ocalib.calibnet.run import calibrate_images
from ocalib.calibnet.sequence import open_calibration_sequence
from ocalib.frontend import FRONTENDS, FrontEndOptions
from ocalib.rigba.online import OnlineRigOptions
from ocalib.rigba.options import BundleOptions, FeatureOptions, MapperOptions
from ocalib.rigba.stream import OnlineRigStage

KEYS = ("rotation_deg", "direction_deg", "translation_rel_baseline")
VARIANTS = {"sim3": None, "prior": "--metric-noise", "held": 0.0}  # the adjustment's metric_noise (prior: the flag's)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_sequence_arguments(p, ["handheld-1001", "front-left-1008", "handheld-2001", "front-left-2002"])
    p.add_argument("--frontends", nargs="+", choices=FRONTENDS, default=["network"])
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--metric-noise", type=float, default=0.001, help="the priors' noise, metres per axis")
    p.add_argument("--trajectory-noise", nargs=2, type=float, metavar=("METRES", "DEG"), default=(0.0, 0.0),
                   help="Gaussian noise added to each pose of the trajectory the adjustments get (a seeded draw)")  # fmt: skip
    p.add_argument("--variants", nargs="+", choices=list(VARIANTS), default=list(VARIANTS))
    p.add_argument("--out", default="bench/results/metric_prior.json")
    args = p.parse_args()
    results = {}
    print(f"{'sequence':18} {'front end':9} {'estimator (rot/dir/t)':>22}" + "".join(f"{v:>18}" for v in args.variants))
    for name in args.sequences:
        path = ensure(Path(args.root), name, args.frames)
        for frontend in args.frontends:
            rows = results.setdefault(Path(path).name, {})[frontend] = run(path, frontend, args)
            cells = ["/".join(f"{rows[t][k]:.2f}" for k in KEYS) if rows[t] else "not started"
                     for t in ("rig_estimator", *args.variants)]  # fmt: skip
            print(
                f"{Path(path).name:18} {frontend:9} {cells[0]:>22}" + "".join(f"{c:>18}" for c in cells[1:]), flush=True
            )
            write_json(args.out, {"frames": args.frames, "metric_noise": args.metric_noise,
                                  "trajectory_noise": args.trajectory_noise, "results": results})  # fmt: skip


def noisy(poses: np.ndarray, metres: float, degrees: float, seed: int = 0) -> np.ndarray:
    """``poses`` (T, 4, 4) with independent Gaussian noise on each position (``metres`` per axis) and rotation
    (``degrees`` about each axis, applied on the left)."""
    rng, out = np.random.default_rng(seed), poses.copy()
    out[:, :3, 3] += rng.normal(0.0, metres, (len(poses), 3))
    turn = Rotation.from_rotvec(rng.normal(0.0, np.radians(degrees), (len(poses), 3))).as_matrix()
    out[:, :3, :3] = turn @ out[:, :3, :3]
    return out


def run(path: Path, frontend: str, args) -> dict:
    """One on-line pass with the rig estimator, then the adjustment once per variant."""
    sequence = open_calibration_sequence(path, max_frames=args.frames, frontend=FrontEndOptions(frontend))
    metric = noisy(sequence.cameras[0].poses[: args.frames], *args.trajectory_noise)
    rig = OnlineRigStage(sequence, metric, OnlineRigOptions(metric_noise=0.0))  # the rendered poses are exact: held
    result = calibrate_images(sequence, frontend=FrontEndOptions(frontend), max_frames=args.frames, progress=False,
                              on_frame=rig)  # fmt: skip
    rig.attach(result)
    rows = {"rig_estimator": None if result.rig_errors is None else errors_row(result.rig_errors[0]), "raw": {
        "truth": result.truth.tolist(),
        "rig_estimator": None if rig.final is None else {
            "extrinsics": rig.final.extrinsics[1:].tolist(), "std": rig.final.std[1:].tolist()}}}  # fmt: skip
    for tag in args.variants:
        noise = args.metric_noise if tag == "prior" else VARIANTS[tag]
        options = BundleOptions(FeatureOptions(threads=1), MapperOptions(threads=1, metric_noise=noise))
        start = time.perf_counter()
        refine_calibration(result, metric, options, progress=False)
        b = result.bundle
        rows[tag] = errors_row(result.bundle_errors[0]) | {
            "trusted": bool(b.trusted[1]), "seconds": time.perf_counter() - start,
            "metric_inside": b.stats.get("metric_inside"), "warnings": b.warnings}  # fmt: skip
        rows["raw"][tag] = {"extrinsics": b.extrinsics[1:].tolist(), "trusted": b.trusted[1:].tolist(),
                            "covariance": [None if u is None else u.covariance.tolist() for u in b.uncertainty[1:]],
                            "unobservable": [None if u is None else u.unobservable.tolist() for u in b.uncertainty[1:]]}  # fmt: skip
    return rows


if __name__ == "__main__":
    main()
