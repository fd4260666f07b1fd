"""A candidate for the head: each direction of the translation rows weighted by its own residual, in batch.

A motion pair gives translation rows in both directions (:mod:`ocalib.calib.handeye`); which direction is the cleaner
depends on which side of a step a front end's noise sits (``drift``: the frame the step ends in; ``drift-start``: the
frame it starts from, :func:`bench_head_accuracy.drift_at_start`). This solves the batch problem on consecutive pairs
of the hand-held trajectory (:func:`bench_head_accuracy.make_setting`) three ways, each refined jointly
(``ocalib.calib.batch``'s Levenberg-Marquardt): rows in both directions weighing alike (``both``, the head's rows),
the forward rows only (``oneway``), and both directions, each re-weighted twice by the inverse of its own mean squared
residual at the estimate (``weighted``). Prints the median final errors (rotation deg / translation over the baseline /
relative scale) and writes ``bench/results/direction_weights.json``.

    python bench/bench_direction_weights.py [--rigs 50] [--frames 128]
"""

from __future__ import annotations

import argparse

import numpy as np
import torch
from bench_head_accuracy import ERRORS, errors, make_setting
from common import write_json

from ocalib.calib import batch
from ocalib.calib.handeye import pair_features, rotation_block
from ocalib.calib.rotation import batch_rotation
from ocalib.geometry.quaternion import quaternion_to_rotation_matrix, rotation_matrix_to_quaternion

MODES = ("both", "oneway", "weighted")


def solve(poses: torch.Tensor, mode: str) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Rotation (1, 3, 3), translation (1, 3) and scale (1,) of camera 1 from (T, 2, 4, 4) poses."""
    start, end, _ = batch.motion_pairs(poses.shape[0], "consecutive")
    m = batch.pair_motions(poses, start, end)
    q = rotation_matrix_to_quaternion(m[..., :3, :3])
    A = rotation_block(q[:, 0], q[:, 1])
    quat, _, _ = batch_rotation(A[None], torch.ones(1, len(A), dtype=A.dtype))
    z = pair_features(m[:, 0], m[:, 1], mode != "oneway").flatten(0, 1)  # (M D, 15)
    eye = torch.eye(3, dtype=z.dtype)
    R0, t0, t1 = eye - z[:, :9].unflatten(-1, (3, 3)), z[:, 12:], z[:, 9:12]
    weight = torch.ones(len(z), 1, dtype=z.dtype)
    B, b = batch._weighted_rows(R0[None], t0[None], t1[None], quaternion_to_rotation_matrix(quat), weight[None])
    x = (torch.linalg.pinv(B[0]) @ b[0].unsqueeze(-1)).squeeze(-1)
    quat, x = batch._refine(A, R0, t0, t1, weight, quat[0], x, float(len(A)))
    for _ in range(2 if mode == "weighted" else 0):
        residual = (eye - R0) @ x[:3] + x[3] * (quaternion_to_rotation_matrix(quat) @ t1.unsqueeze(-1))[..., 0] - t0
        variance = residual.square().sum(-1).view(-1, 2).mean(0)  # forward, backward
        weight = (variance.min() / variance).sqrt().repeat(len(A))[:, None]
        quat, x = batch._refine(A, R0, t0, t1, weight, quat, x, float(len(A)))
    return quaternion_to_rotation_matrix(quat)[None], x[None, :3], x[None, 3]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rigs", type=int, default=50)
    p.add_argument("--frames", type=int, default=128)
    p.add_argument("--out", default="bench/results/direction_weights.json")
    args = p.parse_args()
    torch.set_num_threads(1)
    results = {}
    print(f"hand-held, {args.rigs} rigs, {args.frames} frames, consecutive pairs; medians rot deg / t rel / scale rel")
    for noise in ("drift", "drift-start"):
        poses, rigs = make_setting("handheld", noise, 0.001, 1.0, args.rigs, args.frames, 10.0, 0.13)
        for mode in MODES:
            e = np.concatenate([errors(*solve(poses[i], mode), rigs[i : i + 1], 1.0) for i in range(len(poses))])
            results[f"{noise} {mode}"] = dict(zip(ERRORS, np.median(e, 0).tolist()))
            print(f"{noise:12} {mode:9} " + " / ".join(f"{v:.4g}" for v in np.median(e, 0)), flush=True)
    write_json(args.out, dict(rigs=args.rigs, frames=args.frames, sigma=0.001, scale=1.0, medians=results))


if __name__ == "__main__":
    main()
