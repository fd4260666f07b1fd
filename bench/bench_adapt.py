"""Does adapting the pose network to the new rig help calibration? (the ``--adapt`` study, docs/calibnet.md)

For each held-out sequence, calibrates camera 1 against camera 0 from images with the checkpoint as it is, then
with copies of the network adapted on the sequence's own frames (test-time training, no ground truth):

* ``photometric``: ``--steps`` steps of the self-supervised loss (minimum reprojection, auto-masking,
  smoothness, geometry consistency; full resolution only) on random snippets of both cameras;
* ``photometric + rig``: the same plus the rig constraint: every synchronised pair of predicted motions
  ``A`` (camera 0) and ``B`` (camera 1) must satisfy ``A X = X B`` for the extrinsic ``X`` (rotation residual
  ``|R_A dR - dR R_B|^2``, translation residual ``|(R_A - I) dT + t_A - s dR t_B|^2`` over ``|t_A|^2``), with ``X``
  and ``s`` optimised alongside, starting from the unadapted network's calibration.

Reports the final rotation, translation direction and relative translation errors and each camera's rotation
gains (1 is unbiased; see ``ocalib.eval.pose_metrics.rotation_gain``). Prints a table, writes JSON.

    python bench/bench_adapt.py [--steps 300] [--sequences DIR ...]
"""

from __future__ import annotations

import argparse
import copy
import random
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from bench_calibnet_accuracy import DEFAULT, ensure
from common import write_json
from kornia.geometry.conversions import axis_angle_to_rotation_matrix
from ocalib.train.module import EgoMotionModule

from ocalib.calibnet.run import calibrate_images
from ocalib.data.layout import open_sequence
from ocalib.data.snippets import SnippetDataset, collate_snippets
from ocalib.eval.pose_metrics import rotation_gain
from ocalib.frontend import FrontEndOptions
from ocalib.models import EgoMotionModel, load_model, save_model

LR, EXTRINSIC_LR, BATCH = 1e-4, 1e-3, 2  # network and extrinsic learning rates; synchronised frames a step
RIG_WEIGHTS = (2.0, 0.05)  # rotation, translation residual weights (100 / 1 collapsed the motions to zero)


def adapt(model: EgoMotionModel, path: Path, steps: int, rig: dict | None, seed: int = 0) -> EgoMotionModel:
    """A copy of ``model`` after ``steps`` self-supervised steps on the sequence's cameras 0 and 1 (with the rig
    constraint from the extrinsic ``rig`` = {"rotation", "translation", "scale"} when given)."""
    random.seed(seed)
    torch.manual_seed(seed)
    module = EgoMotionModule(size=model.size, height=model.height, width=model.width, geometry=0.1, scales=1)
    module.model = copy.deepcopy(model).train()
    seq = open_sequence(path)
    size = (model.height, model.width)
    cams = [SnippetDataset([open_sequence(path, [name])], offsets=(-1, 1), size=size) for name in seq.names[:2]]
    params = [{"params": module.model.parameters(), "lr": LR}]
    if rig is not None:
        dR0 = torch.tensor(rig["rotation"], dtype=torch.float32)
        omega = torch.zeros(3, requires_grad=True)
        dT = torch.tensor(rig["translation"], dtype=torch.float32).requires_grad_()
        log_s = torch.tensor(float(np.log(max(rig["scale"], 1e-3))), requires_grad=True)
        params.append({"params": [omega, dT, log_s], "lr": EXTRINSIC_LR})
    optimiser = torch.optim.Adam(params)
    for _ in range(steps):
        frames = [random.randrange(len(cams[0])) for _ in range(BATCH)]
        batch = collate_snippets([cam[i] for cam in cams for i in frames])  # camera 0's snippets, then camera 1's
        out, _, T = module.step(batch)  # T (2 BATCH, 2, 4, 4): T_target_source
        loss = out.total
        if rig is not None:
            A, B = T[:BATCH].flatten(0, 1), T[BATCH:].flatten(0, 1)
            dR = axis_angle_to_rotation_matrix(omega[None])[0] @ dR0
            rotation = (A[:, :3, :3] @ dR - dR @ B[:, :3, :3]).square().sum((-1, -2)).mean()
            residual = (A[:, :3, :3] - torch.eye(3)) @ dT + A[:, :3, 3] - log_s.exp() * B[:, :3, 3] @ dR.mT
            step = A[:, :3, 3].detach().square().sum(-1).mean().clamp_min(1e-8)  # camera 0's squared step length
            translation = residual.square().sum(-1).mean() / step
            loss = loss + RIG_WEIGHTS[0] * rotation + RIG_WEIGHTS[1] * translation
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    return module.model.eval()


def calibrate(model: EgoMotionModel, path: Path, frames: int, tmp: Path) -> dict:
    """Calibrate with ``model`` -> errors, the extrinsic and the rotation gains of both cameras."""
    checkpoint = save_model(model, tmp / "model.pt")
    out = calibrate_images(
        path, frontend=FrontEndOptions(checkpoint=str(checkpoint)), max_frames=frames, progress=False
    )
    e, cam = out.errors[0], out.run.result_json()["extrinsics"][0]
    seq = open_sequence(path)
    trajectory = out.run.rig.poses
    gains = []
    for c, camera in enumerate(seq.cameras[:2]):
        pred = np.linalg.inv(trajectory[:-1, c]) @ trajectory[1:, c]
        true = np.linalg.inv(camera.poses[: frames - 1]) @ camera.poses[1:frames]
        gains.append([None if not np.isfinite(g) else round(float(g), 3) for g in rotation_gain(pred, true)])
    return {
        "rotation_deg": e["rotation_error_deg"],
        "direction_deg": e["translation_direction_error_deg"],
        "translation_rel_baseline": e.get("translation_error_rel_baseline"),
        "in_plane": e["compared_in_plane"],
        "rotation_gains_xyz": gains,
        "extrinsic": {k: cam[k] for k in ("rotation", "translation", "scale")},
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--root", default="data/eval", help="where held-out sequences live / are rendered")
    p.add_argument("--sequences", nargs="+", default=list(DEFAULT))
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--checkpoint")
    p.add_argument("--out", default="bench/results/adapt.json")
    args = p.parse_args()
    torch.set_num_threads(2)
    model = load_model(args.checkpoint)
    tmp = Path(tempfile.mkdtemp(prefix="ocalib-adapt-"))
    results = {}
    for name in args.sequences:
        path = ensure(Path(args.root), name, args.frames) if name in DEFAULT else Path(name)
        res = results[path.name] = {}
        res["as trained"] = calibrate(model, path, args.frames, tmp)
        for label, rig in (("photometric", None), ("photometric + rig", res["as trained"]["extrinsic"])):
            start = time.perf_counter()
            adapted = adapt(model, path, args.steps, rig)
            res[label] = calibrate(adapted, path, args.frames, tmp) | {"adapt_s": time.perf_counter() - start}
    print(
        f"{'sequence':18} {'network':20} {'rot (deg)':>9} {'dir (deg)':>9} {'t/baseline':>10}  rotation gains (cam0 / cam1)"
    )
    for name, res in results.items():
        for label, r in res.items():
            rel = r["translation_rel_baseline"]
            print(
                f"{name:18} {label:20} {r['rotation_deg']:9.2f} {r['direction_deg']:9.2f} "
                f"{'n/a' if rel is None else f'{rel:10.2f}':>10}  {r['rotation_gains_xyz'][0]} / {r['rotation_gains_xyz'][1]}"
            )
    write_json(
        args.out,
        {"frames": args.frames, "steps": args.steps, "checkpoint": args.checkpoint or "default", "results": results},
    )


if __name__ == "__main__":
    main()
