"""The paper's numerical simulation (section 3.1): per-frame calibration errors over noise levels and seeds.

A random rig (unit baseline) follows a rig trajectory (LDS, car or straight); Gaussian noise perturbs
every pose (``independent``) or every frame-to-frame motion (``drift``); each method calibrates all
seeds and noise levels at once as one batch of rigs, and its error is recorded every frame.

Convention: rigs are ``T_cam0_cam1`` (camera 1's pose in camera 0's frame), true scale 1; rotation
noise is in radians, translation noise in baseline units.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, is_dataclass

import torch
from torch import Tensor

from ocalib.calib.drivers.online import OnlineCalibrator
from ocalib.calib.drivers.sequence import calibrate_sequence
from ocalib.calib.stages.gating import NO_GATES
from ocalib.errors import InputError
from ocalib.geometry.quaternion import rotation_angle, rotation_matrix_to_quaternion
from ocalib.sim.trajectory import (
    add_noise,
    car_trajectory,
    lds_trajectory,
    random_rig,
    rig_trajectories,
    straight_trajectory,
)

_PAPER = dict(motion="first", solver="rls", rls_c0=1.0, rls_delay=0, gates=NO_GATES)

# method name -> OnlineCalibrator keyword arguments
METHODS: dict[str, dict] = {
    "paper-rls": _PAPER,  # the paper: frame-0 pairing, RLS with C0 = I from frame 0, no gating
    "paper-rls-delay": {**_PAPER, "rls_delay": 60},  # the paper's translation started at frame 60
    "default": {},  # ocalib's defaults: exact solver, multi-gap pairing, gating
    "first": {"motion": "first"},  # the default with frame-0 pairing
    "consecutive": {"motion": "consecutive"},  # the default with consecutive pairing
}
# any other pairing: "gaps-1-2-4-8" is the default with motion=(1, 2, 4, 8) (gap 0: the pair with frame 0); the gaps
# are weighted by their noise as in the default (ocalib.calib.stages.pairing)

ERRORS = ("rotation_deg", "axis_deg", "translation_direction_deg", "translation_rel", "scale_rel")
ERROR_LABELS = {
    "rotation_deg": "rotation error (deg)",
    "axis_deg": "rotation axis error (deg)",
    "translation_direction_deg": "translation direction error (deg)",
    "translation_rel": "translation error / baseline",
    "scale_rel": "relative scale error",
}
NOISE_MODELS = ("independent", "drift")
TRAJECTORIES = ("lds", "car", "straight")


@dataclass
class SimulationResult:
    """Per-frame errors of every method: ``errors[method]`` is (noise levels, seeds, frames, len(ERRORS));
    ``methods[method]`` its ``OnlineCalibrator`` keyword arguments."""

    noise: list[float]
    seeds: int
    frames: int
    noise_model: str
    trajectory: str
    methods: dict[str, dict]
    errors: dict[str, Tensor]

    def curves(self, method: str) -> Tensor:
        """Median over seeds, (noise levels, frames, len(ERRORS)); NaN-free where any seed is finite."""
        return self.errors[method].nanmedian(1).values

    def summary(self) -> dict:
        """Final-frame errors: ``{method: {noise: {error: {"median", "mean", "max"}}}}`` plus the setup."""
        out = {}
        for method, err in self.errors.items():
            final = err[:, :, -1]  # (N, S, E)
            out[method] = {
                f"{sigma:g}": {
                    name: {
                        "median": float(final[i, :, j].nanmedian()),
                        "mean": float(final[i, :, j].nanmean()),
                        "max": float(final[i, :, j].nan_to_num(math.inf).max()),
                    }
                    for j, name in enumerate(ERRORS)
                }
                for i, sigma in enumerate(self.noise)
            }
        setup = dict(
            noise=self.noise,
            seeds=self.seeds,
            frames=self.frames,
            noise_model=self.noise_model,
            trajectory=self.trajectory,
            methods={m: _jsonable(k) for m, k in self.methods.items()},
        )
        return {"setup": setup, "final": out}


def make_rigs(
    noise: list[float], seeds: int, frames: int, noise_model: str = "independent", trajectory: str = "lds"
) -> tuple[Tensor, Tensor]:
    """Noisy rig trajectories and true rigs.

    Seed i draws the same rig, trajectory and (unit) noise at every noise level (common random numbers).

    Returns:
        poses (N * S, frames, 2, 4, 4) camera-to-world, noise level major; rigs (N * S, 4, 4) ``T_cam0_cam1``.
    """
    _check(noise, seeds, frames, noise_model, trajectory)
    poses, rigs = [], []
    for sigma in noise:
        for seed in range(seeds):
            g = torch.Generator().manual_seed(seed)
            rig = random_rig(g)
            if trajectory == "lds":
                cam0 = lds_trajectory(frames, g)
            elif trajectory == "car":
                cam0 = car_trajectory(frames, g, pitch_roll=0.002)
            else:
                cam0 = straight_trajectory(frames)
            clean = rig_trajectories(cam0, rig[None])
            poses.append(add_noise(clean, sigma, torch.Generator().manual_seed(10_000 + seed), noise_model))
            rigs.append(rig)
    return torch.stack(poses), torch.stack(rigs)


def calibration_errors(rotation: Tensor, translation: Tensor, scale: Tensor, rig: Tensor) -> Tensor:
    """Errors of estimates against true rigs (true scale 1).

    Args: rotation (B, 3, 3), translation (B, 3), scale (B,), rig (B, 4, 4) ``T_cam0_cam1``.
    Returns: (B, len(ERRORS)) in the order of :data:`ERRORS` (degrees for angles; NaN where undefined).
    """
    R, t = rig[:, :3, :3], rig[:, :3, 3]
    rot = rotation_angle(rotation.mT @ R)
    axis_hat, axis = _axis(rotation), _axis(R)
    axis_err = torch.atan2(torch.linalg.cross(axis_hat, axis).norm(dim=-1), (axis_hat * axis).sum(-1))
    direction = torch.atan2(torch.linalg.cross(translation, t).norm(dim=-1), (translation * t).sum(-1))
    direction = torch.where(translation.norm(dim=-1) > 0, direction, torch.nan)  # no estimate yet
    rel = (translation - t).norm(dim=-1) / t.norm(dim=-1)
    return torch.stack(
        [torch.rad2deg(rot), torch.rad2deg(axis_err), torch.rad2deg(direction), rel, (scale - 1).abs()], -1
    )


def run_method(poses: Tensor, rigs: Tensor, progress=None, **kwargs) -> Tensor:
    """Calibrate every rig on-line with ``OnlineCalibrator(**kwargs)``; ``progress()`` is called every frame.

    The exact solver runs through the whole-sequence path (:func:`~ocalib.calib.drivers.sequence.calibrate_sequence`,
    the same per-frame estimates, faster); the RLS streams the frames. One intra-op thread (small tensors).

    Args: poses (B, T, 2, 4, 4), rigs (B, 4, 4). Returns per-frame errors (B, T, len(ERRORS)).
    """
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        with torch.no_grad():
            if kwargs.get("solver", "exact") == "exact":
                out = calibrate_sequence(poses.transpose(0, 1), **kwargs)
                errors = [calibration_errors(out.rotation[t, :, 0], out.translation[t, :, 0], out.scale[t, :, 0], rigs)
                          for t in range(poses.shape[1])]  # fmt: skip
                for _ in range(poses.shape[1] if progress is not None else 0):
                    progress()
                return torch.stack(errors, 1)
            cal = OnlineCalibrator(num_cameras=2, batch_size=poses.shape[0], **kwargs)
            errors = []
            for t in range(poses.shape[1]):
                out = cal(poses[:, t])
                errors.append(calibration_errors(out.rotation[:, 0], out.translation[:, 0], out.scale[:, 0], rigs))
                if progress is not None:
                    progress()
            return torch.stack(errors, 1)
    finally:
        torch.set_num_threads(threads)


def simulate(
    noise: list[float],
    seeds: int = 20,
    frames: int = 128,
    noise_model: str = "independent",
    trajectory: str = "lds",
    methods: dict[str, dict] | list[str] = ("paper-rls", "paper-rls-delay", "default"),
    progress=None,
) -> SimulationResult:
    """Run the simulation for every method (names for :func:`method_kwargs`, or name -> calibrator kwargs).

    ``progress``, if given, is called after every frame of every method.
    """
    if not isinstance(methods, dict):
        methods = {m: method_kwargs(m) for m in methods}
    poses, rigs = make_rigs(noise, seeds, frames, noise_model, trajectory)
    errors = {}
    for name, kwargs in methods.items():
        errors[name] = run_method(poses, rigs, progress, **kwargs).reshape(len(noise), seeds, frames, len(ERRORS))
    return SimulationResult(list(noise), seeds, frames, noise_model, trajectory, methods, errors)


def method_kwargs(name: str) -> dict:
    """``OnlineCalibrator`` keyword arguments of a method name: a key of :data:`METHODS` or ``gaps-G1-G2-...``."""
    if name in METHODS:
        return METHODS[name]
    gaps = name.split("-")[1:]
    if name.startswith("gaps-") and gaps and all(g.isdigit() for g in gaps):
        return {"motion": tuple(int(g) for g in gaps)}
    raise InputError(f"unknown method {name!r}; choose from {', '.join(METHODS)} or gaps-G1-G2-... (e.g. gaps-1-2-4-8)")


def _axis(R: Tensor) -> Tensor:
    """Unit rotation axes (B, 3) of rotations (B, 3, 3) (quaternion w >= 0)."""
    v = rotation_matrix_to_quaternion(R)[..., 1:]
    return v / v.norm(dim=-1, keepdim=True)


def _check(noise, seeds, frames, noise_model, trajectory) -> None:
    if not noise or any(not math.isfinite(s) or s < 0 for s in noise):
        raise InputError(f"noise levels must be finite and >= 0, got {list(noise)}")
    if seeds < 1:
        raise InputError(f"seeds must be >= 1, got {seeds}")
    if frames < 2:
        raise InputError(f"frames must be >= 2, got {frames}")
    if noise_model not in NOISE_MODELS:
        raise InputError(f"noise model must be one of {', '.join(NOISE_MODELS)}, got {noise_model!r}")
    if trajectory not in TRAJECTORIES:
        raise InputError(f"trajectory must be one of {', '.join(TRAJECTORIES)}, got {trajectory!r}")


def _jsonable(kwargs: dict) -> dict:
    """A method's keyword arguments as JSON values (gaps as lists, :class:`~ocalib.calib.stages.gating.Gates` as a
    dict)."""
    return {k: list(v) if isinstance(v, tuple) else (asdict(v) if is_dataclass(v) else v) for k, v in kwargs.items()}
