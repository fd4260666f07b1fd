"""Where frame-0 pairing's translation comes from: its rows solved at a fixed rotation against its joint refinement.

Under independent noise on every pose, frame-0 pairing (``batch_calibrate(motion="first")``, rows one way) is the
best batch reference for translation. This bench solves the same rows' translation and scale by least squares at
a given rotation -- the head's final one, and the true one -- beside the reference's own joint refinement and the
head, on the rigs of ``bench_head_accuracy.py`` (same seeds). A translation-only channel on frame-0 rows would be
the fixed-rotation solve.

Prints medians and means over the rigs and writes ``bench/results/frame0_rows.json``.

    python bench/bench_frame0_rows.py [--rigs 50] [--trajectories lds handheld]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from bench_head_accuracy import errors, make_setting
from common import write_json

from ocalib.calib.batch import batch_calibrate
from ocalib.calib.handeye import translation_rows
from ocalib.calib.online import OnlineCalibrator
from ocalib.calib.translation import symmetric_scale

OUT = Path(__file__).parent / "results" / "frame0_rows.json"
FRAMES, SIGMA, RATE, BASELINE = 128, 0.01, 10.0, 0.13  # bench_head_accuracy's defaults, independent noise, scale 1


def solve_at(features: torch.Tensor, rotation: torch.Tensor) -> torch.Tensor:
    """``(dT, s)`` (4,) of one camera's translation rows (``features`` (rows, 15): vec(I - R0), t1, t0) at
    ``rotation`` (3, 3): least squares, the scale re-fitted symmetrically (the head's default)."""
    eye = torch.eye(3, dtype=features.dtype)
    R0 = eye - features[:, :9].unflatten(-1, (3, 3))
    B, t0 = translation_rows(R0, features[:, 12:], features[:, 9:12], rotation)
    B, t0 = B.flatten(0, 1), t0.flatten(0, 1)
    H, g = B.mT @ B, B.mT @ t0
    return symmetric_scale(H, g, t0.square().sum(), torch.linalg.solve(H, g))


def run(trajectory: str, rigs: int) -> dict[str, np.ndarray]:
    """Final errors (rigs, 3) of the head, the reference and the fixed-rotation solves."""
    poses, truth = make_setting(trajectory, "independent", SIGMA, 1.0, rigs, FRAMES, RATE, BASELINE)
    head = OnlineCalibrator(num_cameras=2, batch_size=rigs)
    with torch.no_grad():
        for t in range(poses.shape[1]):
            out = head(poses[:, t])
    found = {"head": errors(out.rotation[:, 0], out.translation[:, 0], out.scale[:, 0], truth, 1.0)}
    rows = {"first-oneway (refined)": [], "rows at the head's rotation": [], "rows at the true rotation": []}
    for b in range(rigs):
        ref = batch_calibrate(poses[b], motion="first", symmetric=False)
        rows["first-oneway (refined)"].append(
            errors(ref["rotation"][:1], ref["translation"][:1], ref["scale"][:1], truth[b : b + 1], 1.0)
        )
        for name, R in (
            ("rows at the head's rotation", out.rotation[b, 0]),
            ("rows at the true rotation", truth[b, :3, :3]),
        ):
            x = solve_at(ref["features"][0], R)
            rows[name].append(errors(R[None], x[None, :3], x[None, 3], truth[b : b + 1], 1.0))
    return found | {name: np.concatenate(e) for name, e in rows.items()}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rigs", type=int, default=50)
    p.add_argument("--trajectories", nargs="+", default=["lds", "handheld"], choices=("lds", "handheld"))
    args = p.parse_args()
    if args.rigs < 1:
        p.error(f"--rigs {args.rigs}: need at least one rig")
    results = {}
    print(f"{'trajectory':<10} {'solve':<30} {'rot deg':>8} {'t rel':>8} {'(mean)':>8}   medians over {args.rigs} rigs")
    for trajectory in args.trajectories:
        for name, e in run(trajectory, args.rigs).items():
            med = np.median(e, 0)
            print(f"{trajectory:<10} {name:<30} {med[0]:>8.3f} {med[1]:>8.4f} {e[:, 1].mean():>8.4f}")
            results.setdefault(trajectory, {})[name] = {
                "rotation_deg_median": float(med[0]),
                "translation_rel_median": float(med[1]),
                "translation_rel_mean": float(e[:, 1].mean()),
            }
    write_json(OUT, {"rigs": args.rigs, "frames": FRAMES, "sigma": SIGMA, "results": results})


if __name__ == "__main__":
    main()
