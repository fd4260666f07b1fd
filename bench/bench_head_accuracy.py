"""Accuracy of the streaming head (``OnlineCalibrator()``, its defaults) against the best batch solve, in simulation.

For each setting -- trajectory x pose noise x scale of camera 1's units -- the same ``--rigs`` random rigs (a
random rotation and a unit baseline, as in the paper's section 3.1) are calibrated

* by the head, streamed frame by frame, all rigs as one batch of B rigs (the compiled kernel on this CPU), and
* by :func:`~ocalib.calib.drivers.batch.batch_calibrate` on the whole sequence, once per rig, with frame-0 pairing
  (``motion="first"``: every frame against frame 0, the paper's) and with consecutive pairing (``"consecutive"``),
  each with the joint refinement (``refine=True``, which was better than the closed form everywhere, measured),
  with translation rows in both directions (``symmetric=True``) and in one (``False``, ``-oneway``), and with both
  scale fits: least squares' regression (``scale_fit="regression"``, the paper's) and the symmetric fit
  (``"symmetric"``, ``-symscale``; computed from the same solve's rows): eight references.

Errors of the last frame: rotation (deg), translation error / baseline, relative scale error ``|s_hat / s - 1|``;
medians, means and 90th percentiles over the rigs. Each of the head's errors is given as the ratio to the best
of the four references *for that error and statistic* (the references trade rotation for scale differently).

Trajectories (camera 0's; camera 1 follows rigidly):

* ``lds``: the paper's linear dynamic system (:func:`~ocalib.sim.trajectory.lds_trajectory`, about 5 deg and
  0.35 baseline a frame);
* ``handheld``: a person walking with the rig (:func:`ocalib.synth.trajectory.trajectory`, kind ``handheld``: step
  bounce, sway, +-20/8/5 deg yaw/pitch/roll wander), ``--handheld-rate`` frames a second, positions in units of a
  ``--handheld-baseline`` m rig baseline (the renderer's hand-held preset: 10 Hz, 0.13 m).

Noise (:func:`~ocalib.sim.trajectory.add_noise`): ``independent`` perturbs every pose on its own (a SLAM system,
the paper's simulation), ``drift`` every frame-to-frame motion, accumulated (visual odometry), in the frame the
step ends in; ``drift-start`` (:func:`drift_at_start`) in the frame it starts from; ``sigma`` radians and units of
each camera's *own* trajectory (a front end's noise lives in its units). Scale ``s``: camera 1's
translations are divided by ``s`` before the noise (``rig_trajectories(..., scales)``), so at ``s = 2.5`` its
translation noise is 2.5 times larger against its motion than camera 0's.

Heads (``--heads``): the default, and the default with least squares' scale (``scale_fit="regression"``, the
default before the symmetric scale fit). Prints one table (ratios of medians and of means; ``*`` marks a ratio
above ``--target``; the 90 % interval of each ratio of medians over rigs resampled with replacement) and writes
``bench/results/head_accuracy.json``.

    python bench/bench_head_accuracy.py [--rigs 50] [--frames 128] [--trajectories lds handheld]
        [--noise independent:0.01 drift:0.001] [--scales 1 2.5] [--heads '{"default": {}}'] [--out PATH]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch
from common import write_json

from ocalib.calib.drivers.batch import batch_calibrate
from ocalib.calib.drivers.online import OnlineCalibrator
from ocalib.calib.stages.handeye import translation_rows
from ocalib.calib.stages.translation import symmetric_scale
from ocalib.geometry.pose import rereference
from ocalib.geometry.quaternion import rotation_angle
from ocalib.sim.trajectory import add_noise, lds_trajectory, random_rig, rig_trajectories
from ocalib.synth.trajectory import trajectory as synth_trajectory

ERRORS = ("rotation_deg", "translation_rel", "scale_rel")
STATISTICS = ("median", "mean", "p90")
SOLVES = {
    "first": dict(motion="first", refine=True, symmetric=True),
    "first-oneway": dict(motion="first", refine=True, symmetric=False),
    "consecutive": dict(motion="consecutive", refine=True, symmetric=True),
    "consecutive-oneway": dict(motion="consecutive", refine=True, symmetric=False),
}  # each solved with scale_fit="regression"; the "-symscale" references re-fit its scale symmetrically
REFERENCES = [name + fit for name in SOLVES for fit in ("", "-symscale")]
# the heads measured: the default, and the default with least squares' scale (the default before the symmetric fit)
HEADS = {"default": {}, "regression": {"scale_fit": "regression"}}


def make_setting(
    trajectory: str, noise: str, sigma: float, scale: float, rigs: int, frames: int, rate: float, baseline: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """Noisy poses (rigs, frames, 2, 4, 4) and true rigs (rigs, 4, 4); rig i is the same in every setting."""
    poses, truth = [], []
    for seed in range(rigs):
        g = torch.Generator().manual_seed(seed)
        rig = random_rig(g)
        if trajectory == "lds":
            cam0 = lds_trajectory(frames, g)
        else:
            cam0 = torch.from_numpy(synth_trajectory(trajectory, frames, rate, seed))
            cam0[:, :3, 3] /= baseline  # in units of the rig's baseline
            cam0 = rereference(cam0)
        clean = rig_trajectories(cam0, rig[None], torch.tensor([scale], dtype=torch.float64))
        noise_generator = torch.Generator().manual_seed(10_000 + seed)
        if noise == "drift-start":
            poses.append(drift_at_start(clean, sigma, noise_generator))
        else:
            poses.append(add_noise(clean, sigma, noise_generator, noise))
        truth.append(rig)
    return torch.stack(poses), torch.stack(truth)


def drift_at_start(poses: torch.Tensor, sigma: float, generator: torch.Generator) -> torch.Tensor:
    """Drift with each step's noise in the frame the step starts from (``T_{t+1} = T_t N_t step_t``: a rotation
    error turns the whole step) instead of ``add_noise``'s frame it ends in (``T_t step_t N_t``). Which of the two
    a front end has decides which direction of a motion pair's translation rows is the cleaner one."""
    clean = add_noise(poses, 0.0, generator)
    noise = add_noise(torch.eye(4, dtype=poses.dtype).expand_as(poses).contiguous(), sigma, generator)
    steps = torch.linalg.inv(clean[:-1]) @ clean[1:]
    out = [clean[0]]
    for i in range(len(steps)):
        out.append(out[-1] @ noise[i + 1] @ steps[i])
    return torch.stack(out)


def errors(rotation, translation, scale, rigs, true_scale: float) -> np.ndarray:
    """(B, 3): rotation error (deg), translation error / baseline, relative scale error."""
    rot = torch.rad2deg(rotation_angle(rotation.mT @ rigs[:, :3, :3]))
    t = (translation - rigs[:, :3, 3]).norm(dim=-1) / rigs[:, :3, 3].norm(dim=-1)
    return torch.stack([rot, t, (scale / true_scale - 1).abs()], -1).numpy()


def run_head(poses, rigs, scale: float, options: dict) -> tuple[np.ndarray, float]:
    """The head streamed frame by frame, all rigs at once: final errors (B, 3) and seconds a frame."""
    head = OnlineCalibrator(num_cameras=2, batch_size=poses.shape[0], **options)
    start = time.perf_counter()
    with torch.no_grad():
        for t in range(poses.shape[1]):
            out = head(poses[:, t])
    per_frame = (time.perf_counter() - start) / poses.shape[1]
    return errors(out.rotation[:, 0], out.translation[:, 0], out.scale[:, 0], rigs, scale), per_frame


def run_batch(poses, rigs, scale: float, options: dict) -> tuple[np.ndarray, np.ndarray]:
    """``batch_calibrate(scale_fit="regression")`` on each rig's whole sequence, and the same solve with its scale
    re-fitted symmetrically at its rotation (what ``scale_fit="symmetric"`` does; one motion gap, so every row
    weighs 1): final errors (B, 3) of both."""
    regression, symmetric = [], []
    for b in range(poses.shape[0]):
        out = batch_calibrate(poses[b], scale_fit="regression", **options)
        x = torch.cat([out["translation"], out["scale"][:, None]], -1)
        sym = symmetric_fit(out["features"], out["rotation"], x)
        truth = rigs[b : b + 1]
        regression.append(errors(out["rotation"][:1], x[:1, :3], x[:1, 3], truth, scale))
        symmetric.append(errors(out["rotation"][:1], sym[:1, :3], sym[:1, 3], truth, scale))
    return np.concatenate(regression), np.concatenate(symmetric)


def symmetric_fit(features: torch.Tensor, rotation: torch.Tensor, x: torch.Tensor | None = None) -> torch.Tensor:
    """``(dT, s)`` (..., 4) of translation rows with ``features`` (..., rows, 15: vec(I - R0), t1, t0, as
    ``batch_calibrate`` returns them; every row weighs 1) at ``rotation`` (..., 3, 3): ``x`` (least squares' where
    None) with its scale re-fitted symmetrically (what ``scale_fit="symmetric"`` does)."""
    eye = torch.eye(3, dtype=features.dtype)
    R0 = eye - features[..., :9].unflatten(-1, (3, 3))
    B, t0 = translation_rows(R0, features[..., 12:], features[..., 9:12], rotation.unsqueeze(-3))
    B, t0 = B.flatten(-3, -2), t0.flatten(-2)
    H, g = B.mT @ B, (B.mT @ t0[..., None])[..., 0]
    return symmetric_scale(H, g, t0.square().sum(-1), torch.linalg.solve(H, g) if x is None else x)


def statistics(e: np.ndarray) -> dict:
    """{error: {statistic: value}} of final errors (B, 3)."""
    values = {"median": np.median(e, 0), "mean": e.mean(0), "p90": np.quantile(e, 0.9, 0)}
    return {name: {s: float(values[s][i]) for s in STATISTICS} for i, name in enumerate(ERRORS)}


def bootstrap_ratio(head: np.ndarray, references: list[np.ndarray], draws: int = 2000, seed: int = 0) -> np.ndarray:
    """90 % interval (3, 2) of each error's ratio of medians, the head's (B, 3) to the best reference's ((B, 3) each),
    over rigs drawn with replacement (the same rigs for the head and every reference)."""
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(head), (draws, len(head)))
    best = np.min([np.median(r[idx], 1) for r in references], 0)  # (draws, 3)
    return np.quantile(np.median(head[idx], 1) / best, [0.05, 0.95], 0).T


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rigs", type=int, default=50)
    p.add_argument("--frames", type=int, default=128)
    p.add_argument("--trajectories", nargs="+", default=["lds", "handheld"], choices=("lds", "handheld"))
    p.add_argument("--noise", nargs="+", default=["independent:0.01", "drift:0.001"], help="model:sigma")
    p.add_argument("--scales", nargs="+", type=float, default=[1.0, 2.5])
    p.add_argument("--handheld-rate", type=float, default=10.0, help="frames a second")
    p.add_argument("--handheld-baseline", type=float, default=0.13, help="rig baseline in m (the trajectory's unit)")
    p.add_argument("--heads", default=json.dumps(HEADS), help="name -> OnlineCalibrator keyword arguments (JSON)")
    p.add_argument("--target", type=float, default=1.1, help="largest acceptable ratio to the best batch reference")
    p.add_argument("--out", default="bench/results/head_accuracy.json")
    args = p.parse_args()
    torch.set_num_threads(1)
    heads = json.loads(args.heads)
    print(f"{args.rigs} rigs, {args.frames} frames; final-frame errors; heads: {heads}")
    print("ratio = head / best batch reference for that error (median, mean over rigs); * above the target")
    print(f"{'trajectory':10} {'noise':17} {'scale':>5} {'head':11} | {'rot deg / t rel / scale rel':>30} | "
          f"{'best batch':>28} | {'ratio (median)':>20} | {'ratio (mean)':>20} | 90 % interval of the median ratios")  # fmt: skip
    settings, worst = [], {h: {s: 0.0 for s in ("median", "mean")} for h in heads}
    for trajectory in args.trajectories:
        for spec in args.noise:
            noise, sigma = spec.split(":")
            for scale in args.scales:
                poses, rigs = make_setting(
                    trajectory, noise, float(sigma), scale, args.rigs, args.frames,
                    args.handheld_rate, args.handheld_baseline,
                )  # fmt: skip
                methods, per_frame, per_rig = {}, {}, []
                for name, options in SOLVES.items():
                    regression, symmetric = run_batch(poses, rigs, scale, options)
                    methods[name], methods[name + "-symscale"] = statistics(regression), statistics(symmetric)
                    per_rig += [regression, symmetric]
                best = {e: {s: min(methods[r][e][s] for r in REFERENCES) for s in STATISTICS} for e in ERRORS}
                best_by = {e: {s: min(REFERENCES, key=lambda r: methods[r][e][s]) for s in STATISTICS} for e in ERRORS}
                ratio, interval = {}, {}
                for head, options in heads.items():
                    options = {k: tuple(v) if isinstance(v, list) else v for k, v in options.items()}
                    head_errors, per_frame[head] = run_head(poses, rigs, scale, options)
                    methods[head] = statistics(head_errors)
                    ratio[head] = {e: {s: methods[head][e][s] / best[e][s] for s in STATISTICS} for e in ERRORS}
                    interval[head] = dict(zip(ERRORS, bootstrap_ratio(head_errors, per_rig).tolist()))
                    for s in worst[head]:
                        worst[head][s] = max(worst[head][s], *(ratio[head][e][s] for e in ERRORS))

                    def cells(m, s="median"):
                        return " / ".join(f"{m[e][s]:.3g}" for e in ERRORS)

                    def ratios(s, r=ratio[head]):
                        return " / ".join(f"{r[e][s]:.2f}" + ("*" if r[e][s] > args.target else " ") for e in ERRORS)

                    print(f"{trajectory:10} {noise + ' ' + sigma:17} {scale:5g} {head:11} | {cells(methods[head]):>30} | "
                          f"{cells(best):>28} | {ratios('median'):>20} | {ratios('mean'):>20} | "
                          + " / ".join(f"{a:.2f}-{b:.2f}" for a, b in interval[head].values()), flush=True)  # fmt: skip
                settings.append(
                    dict(trajectory=trajectory, noise=noise, sigma=float(sigma), scale=scale, methods=methods,
                         best=best, best_by=best_by, ratio=ratio, ratio_median_interval90=interval,
                         head_seconds_per_frame=per_frame)
                )  # fmt: skip
    for head in heads:
        print(f"{head}: worst ratio, median {worst[head]['median']:.2f}, mean {worst[head]['mean']:.2f} "
              f"(target {args.target})")  # fmt: skip
    write_json(
        args.out,
        dict(
            heads=heads, rigs=args.rigs, frames=args.frames, handheld_rate=args.handheld_rate,
            handheld_baseline_m=args.handheld_baseline, references=SOLVES, errors=list(ERRORS),
            target=args.target, worst_ratio=worst, settings=settings,
        ),
    )  # fmt: skip


if __name__ == "__main__":
    main()
