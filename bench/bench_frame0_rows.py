"""Where frame-0 pairing's translation comes from, and a frame-0 channel that would not cost its rotation.

Under independent noise on every pose, frame-0 pairing (``batch_calibrate(motion="first")``, rows one way) is the
best batch reference for translation. On the rigs of ``bench_head_accuracy.py`` (same seeds, scale 1) this bench
solves the same frame-0 motions

* by least squares on their translation rows at a fixed rotation -- the head's final one, and the true one (what
  a translation-only channel on those rows would do), and
* as ``A_t X = Y B_t`` (:func:`nuisance_solve`): every frame-0 motion ``A_t = T_0^-1 T_t`` of camera 0 carries
  frame 0's pose error ``E_0`` and camera 1's ``E_1`` (``A~_t = E_0^-1 A_t N_t``), so ``A~_t X = Y B~_t`` with
  ``Y = E_0^-1 X E_1``: frame 0's error as a nuisance transform ``Y`` near ``X`` (a Gaussian prior of ``--prior``
  radians and units on their difference), solved by Levenberg-Marquardt from the head's estimate with each kind of
  row weighed by its residual variance (two rounds),

beside the reference's joint refinement and the head; and the head's rotation with its translation and scale
mixed with ``A X = Y B``'s by the weight of the head's longest gap (``w`` of
:func:`~ocalib.calib.stages.pairing.gap_weights`: 0 under drift, 0.3-1 under independent noise). Prints medians and
means over the rigs and writes ``bench/results/frame0_rows.json``.

    python bench/bench_frame0_rows.py [--rigs 50] [--trajectories lds handheld]
        [--noise independent:0.01 drift:0.001] [--prior 0.02]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from bench_head_accuracy import errors, make_setting, symmetric_fit
from common import write_json
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from ocalib.calib.drivers.batch import batch_calibrate
from ocalib.calib.drivers.online import OnlineCalibrator
from ocalib.calib.stages.pairing import gap_weights

OUT = Path(__file__).parent / "results" / "frame0_rows.json"
FRAMES, RATE, BASELINE = 128, 10.0, 0.13  # bench_head_accuracy's defaults


def nuisance_solve(poses: np.ndarray, R: np.ndarray, t: np.ndarray, s: float, prior: float) -> tuple:
    """``(R_x, t_x, s)`` of ``A_t X = Y B_t`` on the frame-0 motions of ``poses`` (T, 2, 4, 4), from ``(R, t, s)``.

    Unknowns: ``R_x = R exp(a)``, ``t_x``, ``s``, ``R_y = R_x exp(b)``, ``t_y = t_x + c``; rows: ``R_A R_x - R_y R_B``
    (rotation) and ``R_A t_x + t_A - s R_y t_B - t_y`` (translation), each kind weighed by its residual's RMS (from
    the start, then at the solution), and ``(b, c) / prior``.
    Convention: ``X = T_cam0_cam1``; ``s`` multiplies camera-1 units into camera-0 units."""
    A = np.linalg.inv(poses[0, 0]) @ poses[1:, 0]
    B = np.linalg.inv(poses[0, 1]) @ poses[1:, 1]
    RA, tA, RB, tB = A[:, :3, :3], A[:, :3, 3], B[:, :3, :3], B[:, :3, 3]

    def residuals(p, w_rotation, w_translation):
        Rx = R @ Rotation.from_rotvec(p[:3]).as_matrix()
        Ry = Rx @ Rotation.from_rotvec(p[7:10]).as_matrix()
        rotation = (RA @ Rx - Ry @ RB).ravel()
        translation = (RA @ p[3:6] + tA - p[6] * tB @ Ry.T - (p[3:6] + p[10:13])).ravel()
        return np.concatenate([w_rotation * rotation, w_translation * translation, p[7:13] / prior])

    p = np.concatenate([np.zeros(3), t, [s], np.zeros(6)])
    weights = (1.0, 1.0)
    for _ in range(2):
        r = residuals(p, 1.0, 1.0)
        n = 9 * len(RA)
        weights = (1 / max(np.sqrt(np.mean(r[:n] ** 2)), 1e-15), 1 / max(np.sqrt(np.mean(r[n:-6] ** 2)), 1e-15))
        p = least_squares(residuals, p, args=weights, method="lm").x
    return R @ Rotation.from_rotvec(p[:3]).as_matrix(), p[3:6], p[6]


def run(trajectory: str, noise: str, sigma: float, rigs: int, prior: float) -> dict[str, np.ndarray]:
    """Final errors (rigs, 3) of the head, the reference and the frame-0 solves."""
    poses, truth = make_setting(trajectory, noise, sigma, 1.0, rigs, FRAMES, RATE, BASELINE)
    head = OnlineCalibrator(num_cameras=2, batch_size=rigs)
    with torch.no_grad():
        for t in range(poses.shape[1]):
            out = head(poses[:, t])
    R, T, S = out.rotation[:, 0], out.translation[:, 0], out.scale[:, 0]
    w = gap_weights(head.gap_S2, head.gap_rotation_rows)[:, 0, -1]  # the longest gap's: 0 under drift
    found = {"head": [errors(R, T, S, truth, 1.0)]}
    for b in range(rigs):
        rig = truth[b : b + 1]
        ref = batch_calibrate(poses[b], motion="first", symmetric=False)
        found.setdefault("first-oneway (refined)", []).append(
            errors(ref["rotation"][:1], ref["translation"][:1], ref["scale"][:1], rig, 1.0)
        )
        for name, rotation in (("rows at the head's rotation", R[b]), ("rows at the true rotation", rig[0, :3, :3])):
            x = symmetric_fit(ref["features"][0], rotation)
            found.setdefault(name, []).append(errors(rotation[None], x[None, :3], x[None, 3], rig, 1.0))
        Rx, tx, s = nuisance_solve(poses[b].numpy(), R[b].numpy(), T[b].numpy(), float(S[b]), prior)
        found.setdefault("A X = Y B, frame 0's error", []).append(
            errors(torch.from_numpy(Rx)[None], torch.from_numpy(tx)[None], torch.tensor([s]), rig, 1.0)
        )
        mixed = w[b] * torch.from_numpy(tx) + (1 - w[b]) * T[b], w[b] * s + (1 - w[b]) * S[b]
        found.setdefault("head + A X = Y B by gap weight", []).append(
            errors(R[b : b + 1], mixed[0][None], mixed[1][None], rig, 1.0)
        )
    return {name: np.concatenate(e) for name, e in found.items()}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rigs", type=int, default=50)
    p.add_argument("--trajectories", nargs="+", default=["lds", "handheld"], choices=("lds", "handheld"))
    p.add_argument("--noise", nargs="+", default=["independent:0.01", "drift:0.001"], help="model:sigma")
    p.add_argument("--prior", type=float, default=0.02, help="sigma of Y's difference from X (radians, units)")
    args = p.parse_args()
    if args.rigs < 1 or not args.prior > 0:
        p.error(f"--rigs {args.rigs} --prior {args.prior}: need at least one rig and a positive prior")
    for spec in args.noise:
        model, _, sigma = spec.partition(":")
        if model not in ("independent", "drift") or not sigma.replace(".", "", 1).isdigit():
            p.error(f"--noise {spec}: expected independent:SIGMA or drift:SIGMA")
    results = []
    print(f"{'setting':<28} {'solve':<30} {'rot deg':>8} {'t rel':>8} {'scale':>9} {'t mean':>8}  (medians)")
    for trajectory in args.trajectories:
        for spec in args.noise:
            noise, sigma = spec.split(":")
            setting = f"{trajectory} {noise} {sigma}"
            for name, e in run(trajectory, noise, float(sigma), args.rigs, args.prior).items():
                med = np.median(e, 0)
                print(f"{setting:<28} {name:<30} {med[0]:>8.3f} {med[1]:>8.4f} {med[2]:>9.2e} {e[:, 1].mean():>8.4f}")
                results.append({"trajectory": trajectory, "noise": noise, "sigma": float(sigma), "solve": name,
                                "median": dict(zip(("rotation_deg", "translation_rel", "scale_rel"), map(float, med))),
                                "translation_rel_mean": float(e[:, 1].mean())})  # fmt: skip
    write_json(OUT, {"rigs": args.rigs, "frames": FRAMES, "prior": args.prior, "results": results})


if __name__ == "__main__":
    main()
