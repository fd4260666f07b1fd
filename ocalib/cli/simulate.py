"""``ocalib simulate``: the paper's numerical simulation (section 3.1), error curves, plots and a summary.

Convention: a random rig of unit baseline and true scale 1; noise in radians (rotation) and baseline
units (translation); errors as in :data:`ocalib.sim.experiment.ERRORS`.
"""

from __future__ import annotations

import argparse

from ocalib.errors import InputError

DEFAULT_NOISE = "0,0.001,0.005,0.01,0.02,0.05,0.1"
DEFAULT_METHODS = "paper-rls,paper-rls-delay,default"


def add_parser(subparsers, name: str) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        name,
        help="the paper's numerical simulation: error curves over noise levels and seeds",
        description="Simulate random rigs on random trajectories with noisy poses, calibrate them on-line with "
        "each method, and write error curves (PNG, TensorBoard) and final errors (summary.json).",
    )
    p.add_argument("--noise", default=DEFAULT_NOISE, help=f"comma-separated noise levels (default {DEFAULT_NOISE})")
    p.add_argument("--seeds", type=int, default=20, help="random rigs per noise level (default 20)")
    p.add_argument("--frames", type=int, default=128, help="frames per trajectory (default 128)")
    p.add_argument(
        "--noise-model",
        choices=("independent", "drift"),
        default="independent",
        help="noise on each pose (the paper) or on each frame-to-frame motion, accumulated (VO-like)",
    )
    p.add_argument(
        "--trajectory",
        choices=("lds", "car", "straight"),
        default="lds",
        help="linear dynamic system (the paper), planar driving with small pitch/roll, or straight",
    )
    p.add_argument(
        "--methods",
        default=DEFAULT_METHODS,
        help=f"comma-separated: paper-rls, paper-rls-delay, default, first, consecutive, or gaps-G1-G2-... "
        f"(default {DEFAULT_METHODS})",
    )
    p.add_argument("--out", default="out/simulate", help="output folder (default out/simulate)")
    p.add_argument("--tensorboard", metavar="DIR", help="also write the median error curves as TensorBoard scalars")
    return p


def run(args: argparse.Namespace) -> int:
    import json
    from pathlib import Path

    from tqdm import tqdm

    from ocalib.sim.experiment import ERRORS, method_kwargs, simulate
    from ocalib.sim.plots import plot_errors

    noise = _floats(args.noise, "--noise")
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    if not methods:
        raise InputError("--methods: give at least one method")
    for m in methods:
        method_kwargs(m)  # fail before simulating
    out = Path(args.out)

    with tqdm(total=len(methods) * args.frames, desc="simulate", unit="frame") as bar:
        result = simulate(noise, args.seeds, args.frames, args.noise_model, args.trajectory, methods, bar.update)

    out.mkdir(parents=True, exist_ok=True)
    summary = result.summary()
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    plot_errors(result, out / "simulation.png")
    for m in methods:
        plot_errors(result, out / f"simulation_{m}.png", [m])

    if args.tensorboard:
        from torch.utils.tensorboard import SummaryWriter

        with SummaryWriter(args.tensorboard) as writer:
            for m in methods:
                curves = result.curves(m)
                for i, sigma in enumerate(noise):
                    for j, name in enumerate(ERRORS):
                        for t, value in enumerate(curves[i, :, j].tolist()):
                            writer.add_scalar(f"{m}/{name}/noise_{sigma:g}", value, t)

    print(f"final errors, median of {args.seeds} seeds ({args.trajectory}, {args.noise_model} noise):")
    print(f"{'method':>18} {'noise':>7} {'rot deg':>9} {'axis deg':>9} {'t dir deg':>9} {'t rel':>9} {'scale':>9}")
    for m in methods:
        for sigma, errs in summary["final"][m].items():
            print(f"{m:>18} {sigma:>7} " + " ".join(f"{errs[e]['median']:9.4g}" for e in ERRORS))
    print(f"wrote {out / 'summary.json'} and {out / 'simulation.png'}")
    return 0


def _floats(text: str, option: str) -> list[float]:
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise InputError(f"{option}: expected comma-separated numbers, got {text!r}") from None
    if not values:
        raise InputError(f"{option}: give at least one value")
    return values
