"""``ocalib demo``: render a small non-overlapping rig, calibrate it from its images, compare with the truth.

The main job of the project: the synthetic renderer makes a sequence with a seed never used in training,
the shipped ego-motion checkpoint and the calibration head calibrate it on-line, and the estimate is
printed beside the rig's true extrinsics, with plots under ``--out``.
"""

from __future__ import annotations

import argparse
import json

from ocalib.cli.options import add_frontend_arguments, frontend_options


def add_parser(subparsers, name: str) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        name,
        help="render a synthetic rig, calibrate it with the shipped checkpoint, print the estimate beside the truth",
        description="Render a non-overlapping rig sequence (synthetic street canyon, held-out seed), calibrate it "
        "from its images (the front end chosen as calibrate chooses it: the pose network on these renders) and the "
        "on-line head, and compare with the true extrinsics. "
        "Writes the sequence, result.json, trace.csv and plots to --out.",
    )
    p.add_argument(
        "--preset", default="handheld", help="synthetic rig: handheld (default), front-left, front-rear, surround"
    )
    p.add_argument("--frames", type=int, default=300, help="frames to render (default 300)")
    p.add_argument("--seed", type=int, default=1001, help="world and trajectory seed (>= 1000: never used in training)")
    p.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    add_frontend_arguments(p, network_options=False)
    p.add_argument("--device", default="cpu", help="torch device (cpu, cuda)")
    p.add_argument(
        "--change",
        action="store_true",
        help="knock camera 1 mid-run (2 deg about its y axis at half the frames; 5 cm sideways too on the cars): "
        "the on-line rig estimator must notice it and follow the new mounting",
    )
    p.add_argument(
        "--bundle-adjust",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="refine by the rig bundle adjustment, in metres through camera 0's rendered poses (as wheel "
        "odometry would give them); default on",
    )
    return p


def run(args) -> int:
    from pathlib import Path

    from ocalib.calib.poses.report import print_warnings, summary
    from ocalib.calibnet.run import calibrate_images
    from ocalib.cli.calibrate import print_errors
    from ocalib.data.layout import open_sequence
    from ocalib.rigba.online import OnlineRigOptions
    from ocalib.rigba.stream import OnlineRigStage
    from ocalib.synth import preset, render_sequence
    from ocalib.synth.presets import knocked
    from ocalib.viz.calibration import bundle_unobservable, plot_trace

    out, frontend = Path(args.out), frontend_options(args)
    cfg = preset(args.preset).with_overrides(frames=args.frames, seed=args.seed)
    if args.change:
        cfg = knocked(cfg, cfg.frames // 2)
    sequence = out / "sequence"
    render_sequence(cfg, sequence, overwrite=True, workers=2)
    metric = open_sequence(sequence).cameras[0].poses  # the rendered poses stand for wheel odometry
    rig = OnlineRigStage(open_sequence(sequence), metric, OnlineRigOptions(metric_noise=0.0))  # exact: held
    result = calibrate_images(sequence, frontend=frontend, device=args.device, on_frame=rig)
    rig.attach(result)
    if args.bundle_adjust:
        from ocalib.calibnet.bundle import refine_calibration

        refine_calibration(result, metric)
    doc = result.result_json()
    (out / "result.json").write_text(json.dumps(doc, indent=2))
    result.run.write_trace(out / "trace.csv")
    plot_trace(
        result.run.trace,
        result.run.rig.files[1:],
        out / "trace.png",
        truth=result.truth,
        units=doc["units"],
        unobservable=bundle_unobservable(doc),
    )
    print(summary(doc))
    print(truth_table(sequence, doc))
    print_errors(result)
    print_warnings(doc)
    print(f"wrote {out / 'result.json'}, {out / 'trace.csv'} and {out / 'trace.png'}")
    return 0


def truth_table(sequence, doc: dict) -> str:
    """Estimated vs true rotation (roll, pitch, yaw) and translation direction of every camera."""
    import numpy as np
    import torch

    from ocalib.data.layout import open_sequence
    from ocalib.geometry.angles import angles_text
    from ocalib.geometry.quaternion import rotation_matrix_to_quaternion

    cams = open_sequence(sequence).cameras
    ref = np.linalg.inv(cams[0].T_cam0_cam)
    lines = ["estimate vs truth (camera k in camera 0's frame):"]
    for cam, e in zip(cams[1:], doc["extrinsics"]):
        T = ref @ (cam.T_cam0_cam if cam.change is None else cam.change.T_cam0_cam)  # at the last frame
        q_true = rotation_matrix_to_quaternion(torch.from_numpy(T[:3, :3])).numpy()
        t, t_true = np.array(e["translation"]), T[:3, 3]
        lines += [
            f"  {cam.name}: rotation {angles_text(np.array(e['quaternion_wxyz']))}",
            f"  {'':{len(cam.name)}}     truth {angles_text(q_true)}",
            f"  {'':{len(cam.name)}}  translation direction {_vec(t / max(np.linalg.norm(t), 1e-12))} vs "
            f"{_vec(t_true / np.linalg.norm(t_true))} (true baseline {np.linalg.norm(t_true):.3f} m)",
        ]
        if doc["units"] == "metres":
            lines.append(f"  {'':{len(cam.name)}}  translation {_vec(t)} m vs {_vec(t_true)} m")
    return "\n".join(lines)


def _vec(v) -> str:
    return "[" + ", ".join(f"{x:+.3f}" for x in v) + "]"
