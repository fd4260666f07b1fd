"""How well the head's reported 1-sigma uncertainties match its actual errors, in simulation.

For random unit-baseline rigs on LDS trajectories (128 frames) with independent or drift noise, calibrates with
the whole-sequence path and divides the final errors by the reported standard deviations, per axis: rotation
(about camera k's axes), translation (camera 0's axes) and scale. An honest 1-sigma gives an RMS of these
z-scores near 1; above 1 the std is optimistic. Prints a table and writes ``bench/results/uncertainty.json``.

    python bench/bench_uncertainty.py [--rigs 60]
"""

from __future__ import annotations

import argparse

import numpy as np
import torch
from common import write_json

from ocalib.calib.drivers.sequence import calibrate_sequence
from ocalib.geometry.se3 import so3_log
from ocalib.sim.trajectory import add_noise, lds_trajectory, random_rig, rig_trajectories

CASES = {"default": {}, "closed form (refine=False)": {"refine": False}, "first": {"motion": "first"},
         "consecutive": {"motion": "consecutive"}}  # fmt: skip


def z_scores(rigs: int, sigma: float, model: str, options: dict, seed: int = 0) -> dict[str, float]:
    """RMS over rigs and axes of error / reported std for rotation, translation and scale."""
    g = torch.Generator().manual_seed(seed)
    z = {"rotation": [], "translation": [], "scale": []}
    for _ in range(rigs):
        rig = random_rig(g)
        poses = add_noise(rig_trajectories(lds_trajectory(128, g), rig[None]), sigma, g, model=model)
        out = calibrate_sequence(poses, **options)
        error = so3_log((out.rotation[-1, 0].mT @ rig[:3, :3]).numpy()[None])[0]
        z["rotation"] += list(error / out.rotation_std[-1, 0].numpy())
        z["translation"] += list((out.translation[-1, 0] - rig[:3, 3]).numpy() / out.translation_std[-1, 0].numpy())
        z["scale"].append(float((out.scale[-1, 0] - 1) / out.scale_std[-1, 0]))
    return {k: float(np.sqrt(np.nanmean(np.square(v)))) for k, v in z.items()}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rigs", type=int, default=60)
    p.add_argument("--out", default="bench/results/uncertainty.json")
    args = p.parse_args()
    torch.set_num_threads(1)
    rows = []
    print(f"RMS of error / reported std over {args.rigs} rigs (1: honest; > 1: optimistic)")
    print(f"{'noise':12} {'sigma':>6} {'head':28} {'rotation':>9} {'translation':>11} {'scale':>7}")
    for model in ("independent", "drift"):
        for sigma in (0.002, 0.01, 0.03):
            for name, options in CASES.items():
                if name != "default" and sigma != 0.01:
                    continue
                r = z_scores(args.rigs, sigma, model, options)
                rows.append({"noise": model, "sigma": sigma, "head": name, **r})
                print(
                    f"{model:12} {sigma:6.3f} {name:28} {r['rotation']:9.2f} {r['translation']:11.2f} {r['scale']:7.2f}",
                    flush=True,
                )
    write_json(args.out, {"rigs": args.rigs, "frames": 128, "results": rows})


if __name__ == "__main__":
    main()
