"""How the joint refinement weighs its rows, in batch: the residual variances that set the weights, and which rows share
one.

The refinement (:mod:`ocalib.calib.stages.refine`, :func:`~ocalib.calib.drivers.batch.batch_calibrate`) weighs the
rotation rows and the translation rows by their residual variances. This solves the batch problem on consecutive pairs
of the hand-held trajectory (:func:`bench_head_accuracy.make_setting`; its best reference under drift) with the
variances

* ``closed form``: of the closed form (rotation first), once;
* ``re-estimated``: of the closed form, then re-estimated at the first solution and solved again;
* ``per direction`` (the default): re-estimated, with a variance for each direction of the translation rows
  (:mod:`ocalib.calib.stages.handeye`: which direction is the cleaner depends on where a front end's noise sits,
  ``drift``: in the frame a step ends in; ``drift-start``, :func:`bench_head_accuracy.drift_at_start`: the one it
  starts from);
* ``one way``: re-estimated, translation rows in one direction only.

Prints the median final errors (rotation deg / translation over the baseline / relative scale, least squares' scale)
and writes ``bench/results/refine_weights.json``.

    python bench/bench_refine_weights.py [--rigs 50] [--frames 128]
"""

from __future__ import annotations

import argparse

import numpy as np
import torch
from bench_head_accuracy import ERRORS, errors, make_setting
from common import write_json

from ocalib.calib.drivers import batch
from ocalib.calib.stages.handeye import pair_features, rotation_block
from ocalib.calib.stages.rotation import batch_rotation
from ocalib.geometry.quaternion import quaternion_to_rotation_matrix, rotation_matrix_to_quaternion

MODES = {  # (rows in both directions, variances a direction, solves)
    "closed form": (True, 1, 1),
    "re-estimated": (True, 1, 2),
    "per direction": (True, 2, 2),
    "one way": (False, 1, 2),
}


def solve(poses: torch.Tensor, mode: str) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Rotation (1, 3, 3), translation (1, 3) and scale (1,) of camera 1 from (T, 2, 4, 4) poses."""
    symmetric, groups, solves = MODES[mode]
    start, end, _ = batch.motion_pairs(poses.shape[0], "consecutive")
    m = batch.pair_motions(poses, start, end)
    q = rotation_matrix_to_quaternion(m[..., :3, :3])
    A = rotation_block(q[:, 0], q[:, 1])
    quat, _, _ = batch_rotation(A[None], torch.ones(1, len(A), dtype=A.dtype))
    z = pair_features(m[:, 0], m[:, 1], symmetric).flatten(0, 1)  # (M D, 15)
    eye = torch.eye(3, dtype=z.dtype)
    R0, t0, t1 = eye - z[:, :9].unflatten(-1, (3, 3)), z[:, 12:], z[:, 9:12]
    weight = torch.ones(len(z), 1, dtype=z.dtype)
    B, b = batch._weighted_rows(R0[None], t0[None], t1[None], quaternion_to_rotation_matrix(quat), weight[None])
    x = (torch.linalg.pinv(B[0]) @ b[0].unsqueeze(-1)).squeeze(-1)
    quat = quat[0]
    for _ in range(solves):
        quat, x = batch._refine(A, R0, t0, t1, weight, quat, x, float(len(A)), groups)
    return quaternion_to_rotation_matrix(quat)[None], x[None, :3], x[None, 3]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rigs", type=int, default=50)
    p.add_argument("--frames", type=int, default=128)
    p.add_argument("--out", default="bench/results/refine_weights.json")
    args = p.parse_args()
    torch.set_num_threads(1)
    results = {}
    print(f"hand-held, {args.rigs} rigs, {args.frames} frames, consecutive pairs; medians rot deg / t rel / scale rel")
    for noise in ("drift", "drift-start"):
        poses, rigs = make_setting("handheld", noise, 0.001, 1.0, args.rigs, args.frames, 10.0, 0.13)
        for mode in MODES:
            e = np.concatenate([errors(*solve(poses[i], mode), rigs[i : i + 1], 1.0) for i in range(len(poses))])
            results[f"{noise} {mode}"] = dict(zip(ERRORS, np.median(e, 0).tolist()))
            print(f"{noise:12} {mode:14} " + " / ".join(f"{v:.4g}" for v in np.median(e, 0)), flush=True)
    write_json(args.out, dict(rigs=args.rigs, frames=args.frames, sigma=0.001, scale=1.0, medians=results))


if __name__ == "__main__":
    main()
