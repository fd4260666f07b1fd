"""``ocalib evaluate --sequence DIR --out metrics.json``: depth and ego-motion metrics of a model on a sequence
with ground truth.

Convention: see :mod:`ocalib.eval.evaluate` (depth: median scaling per image; poses: Sim(3) alignment to
the ground truth re-referenced to its first frame); exported trajectories are KITTI camera-to-first-frame.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ocalib.cli.predict import add_model_arguments


def add_parser(subparsers, name: str) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        name,
        help="depth and pose metrics of an ego-motion model on a sequence with ground truth",
        description="Predict every camera of a sequence and measure it against the ground truth: depth (abs rel, "
        "sq rel, RMSE, RMSE log, delta < 1.25^k, median scaling) and poses (the SfMLearner 5-frame snippet ATE; "
        "ATE and RPE after Sim(3) Umeyama alignment; frame-to-frame rotation and translation-direction errors; "
        "per-frame scale ratio and its coefficient of variation; the rotation gain about each camera axis: 1 is "
        "unbiased, below 1 the model under-reports rotation). Writes the metrics JSON, the predicted "
        "trajectories (KITTI) and optional plots.",
    )
    add_model_arguments(p)
    p.add_argument("--out", required=True, metavar="JSON", help="write the metrics here")
    p.add_argument(
        "--trajectories",
        metavar="DIR",
        help="write <camera>.txt (predicted) and <camera>_sim3.txt (aligned to the ground truth) here "
        "(default: beside the JSON, in <JSON name>_trajectories/)",
    )
    p.add_argument("--plots", metavar="DIR", help="write a figure per camera here (<camera>.png)")
    p.add_argument(
        "--min-depth", type=float, default=1e-3, metavar="M", help="ground-truth depth cap, metres (default 1e-3)"
    )
    p.add_argument(
        "--max-depth", type=float, default=80.0, metavar="M", help="ground-truth depth cap, metres (default 80)"
    )
    p.add_argument("--rpe-delta", type=int, default=1, metavar="N", help="frame gap of the RPE (default 1)")
    return p


def run(args) -> int:
    from ocalib.cli.predict import open_inputs, predict_options
    from ocalib.errors import InputError
    from ocalib.eval.evaluate import evaluate_model, evaluation_json
    from ocalib.io.poses import write_kitti

    if not 0 <= args.min_depth < args.max_depth:
        raise InputError(f"--min-depth {args.min_depth} / --max-depth {args.max_depth}: need 0 <= min < max")
    if args.rpe_delta < 1:
        raise InputError(f"--rpe-delta must be >= 1, got {args.rpe_delta}")
    model, sequence = open_inputs(args)
    results = evaluate_model(
        model,
        sequence,
        args.device,
        predict_options(args),
        progress=None,
        min_depth=args.min_depth,
        max_depth=args.max_depth,
        rpe_delta=args.rpe_delta,
    )
    out = Path(args.out)
    folder = Path(args.trajectories) if args.trajectories else out.with_name(out.stem + "_trajectories")
    doc = {
        "sequence": str(sequence.path),
        "layout": sequence.layout,
        "frames": len(sequence),
        "checkpoint": str(args.checkpoint or "default"),
        "align": args.align,
        "flip": args.flip,
        "model": {"size": model.size, "height": model.height, "width": model.width},
    }
    doc |= evaluation_json(results)
    for r in results:
        files = {"predicted": folder / f"{r.name}.txt"}
        write_kitti(files["predicted"], r.poses)
        if r.details is not None:
            files["sim3_aligned"] = folder / f"{r.name}_sim3.txt"
            write_kitti(files["sim3_aligned"], r.details["aligned"])
        if args.plots:
            from ocalib.eval.plots import plot_camera

            files["plot"] = plot_camera(r, Path(args.plots) / f"{r.name}.png", sequence.name)
        doc["cameras"][r.name]["files"] = {k: str(v) for k, v in files.items()}
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(doc, indent=2))
    print(summary(doc))
    for w in doc["warnings"]:
        print(f"warning: {w}", file=sys.stderr)
    return 0


def summary(doc: dict) -> str:
    """A few lines per camera: the headline depth and pose metrics."""
    lines = [f"{doc['sequence']} ({doc['layout']}, {doc['frames']} frames)"]
    for name, c in doc["cameras"].items():
        lines.append(f"{name}:")
        if c["depth"]:
            d = c["depth"]
            lines.append(
                f"  depth ({d['images']} images): abs rel {d['abs_rel']:.4f}, sq rel {d['sq_rel']:.4f}, "
                f"RMSE {d['rmse']:.3f}, RMSE log {d['rmse_log']:.4f}, "
                f"a1/a2/a3 {d['a1']:.3f}/{d['a2']:.3f}/{d['a3']:.3f}"
            )
            if d.get("by_range"):
                lines.append(
                    "  by true depth (m): "
                    + "; ".join(
                        (f"{r['range_m'][0]:g}-{r['range_m'][1]:g}" if r["range_m"][1] else f">{r['range_m'][0]:g}")
                        + f": {100 * r['share']:.0f} % of pixels, abs rel "
                        f"{r['abs_rel']:.3f}, signed {r['signed_rel']:+.3f}"
                        for r in d["by_range"]
                    )
                )
        if c["pose"]:
            p = c["pose"]
            fmt = lambda v: "n/a" if v is None else f"{v:.4g}"  # noqa: E731
            lines.append(
                f"  pose: SfMLearner 5-frame snippet ATE {fmt(p['sfmlearner_5frame_snippet_ate'])}, "
                f"ATE (Sim3) {fmt(p['ate_rmse'])}, RPE {fmt(p['rpe_trans_rmse'])} / "
                f"{fmt(p['rpe_rot_rmse_deg'])} deg"
            )
            lines.append(
                f"  frame-to-frame: rotation error median {fmt(p['rotation_error_deg_median'])} deg, "
                f"translation direction median {fmt(p['direction_error_deg_median'])} deg, "
                f"scale ratio CV {fmt(p['scale_ratio_cv'])}, "
                f"rotation gain x/y/z {'/'.join(fmt(g) for g in p['rotation_gain_xyz'])}"
            )
            lines.append(
                f"  image-blind baselines: no rotation {fmt(p['baseline_zero_rotation_deg_median'])} deg, "
                f"fixed direction {fmt(p['baseline_constant_direction_deg_median'])} deg, "
                f"fixed step length CV {fmt(p['baseline_constant_step_scale_cv'])}"
            )
    return "\n".join(lines)
