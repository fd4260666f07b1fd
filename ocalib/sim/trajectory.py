"""Synthetic rigs, rig trajectories and pose noise for the calibration simulation.

Convention: poses are camera-to-world 4x4 float64; ``T_cam0_cam1`` is camera 1's pose in camera 0's
frame; a camera-1 trajectory of scale ``s`` has its translations divided by ``s`` (so that ``s``
multiplies camera-1 units into camera-0 units).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from ocalib.geometry import se3
from ocalib.geometry.pose import make_pose, rereference
from ocalib.geometry.quaternion import quaternion_to_rotation_matrix, so3_exp

F64 = torch.float64


def random_rotation(generator: torch.Generator, *shape: int) -> Tensor:
    """Uniformly random rotations (*shape, 3, 3)."""
    q = torch.randn(*shape, 4, generator=generator, dtype=F64)
    return quaternion_to_rotation_matrix(q)


def random_rig(generator: torch.Generator, baseline: float = 1.0) -> Tensor:
    """``T_cam0_cam1`` (4, 4): a random rotation and a random direction of length ``baseline``."""
    t = torch.randn(3, generator=generator, dtype=F64)
    return make_pose(random_rotation(generator), baseline * t / t.norm())


def lds_trajectory(
    n: int,
    generator: torch.Generator,
    rotation_speed: float = 0.05,
    translation_speed: float = 0.2,
    damping: float = 0.95,
) -> Tensor:
    """The paper's linear dynamic system: rotation vector and position driven by damped random velocities.

    ``v_{t+1} = damping v_t + noise``, ``x_{t+1} = x_t + v_t`` for ``x = (rotation vector, position)``.
    Returns camera-0 poses (n, 4, 4) starting at the identity.
    """
    noise_scale = torch.tensor([rotation_speed] * 3 + [translation_speed] * 3, dtype=F64) * math.sqrt(1 - damping**2)
    v = torch.randn(6, generator=generator, dtype=F64) * noise_scale / math.sqrt(1 - damping**2)
    x = torch.zeros(6, dtype=F64)
    states = []
    for _ in range(n):
        states.append(x)
        x = x + v
        v = damping * v + noise_scale * torch.randn(6, generator=generator, dtype=F64)
    states = torch.stack(states)
    return rereference(make_pose(so3_exp(states[:, :3]), states[:, 3:]))


def car_trajectory(
    n: int, generator: torch.Generator, speed: float = 1.0, yaw_rate: float = 0.05, pitch_roll: float = 0.0
) -> Tensor:
    """Planar driving in camera-0 coordinates (x right, y down, z forward): yaw about -y with a
    random, smoothly varying yaw rate, forward speed ``speed`` per frame; optional pitch/roll noise
    (radians) from the road. Returns poses (n, 4, 4), the first the identity."""
    yaw_rates = torch.randn(n, generator=generator, dtype=F64).cumsum(0)
    yaw_rates = yaw_rate * torch.sin(yaw_rates / 3 + torch.rand(1, generator=generator, dtype=F64) * 6)
    yaw = torch.cat([torch.zeros(1, dtype=F64), yaw_rates[:-1].cumsum(0)])
    R = so3_exp(torch.stack([torch.zeros_like(yaw), yaw, torch.zeros_like(yaw)], -1))
    forward = R[:, :, 2]
    position = torch.cat([torch.zeros(1, 3, dtype=F64), (speed * forward[:-1]).cumsum(0)])
    if pitch_roll > 0:
        tilt = pitch_roll * torch.randn(n, 3, generator=generator, dtype=F64) * torch.tensor([1.0, 0.0, 1.0], dtype=F64)
        R = R @ so3_exp(tilt)
    return rereference(make_pose(R, position))


def straight_trajectory(n: int, speed: float = 1.0) -> Tensor:
    """Pure translation along camera 0's optical axis: poses (n, 4, 4)."""
    t = torch.zeros(n, 3, dtype=F64)
    t[:, 2] = speed * torch.arange(n, dtype=F64)
    return make_pose(torch.eye(3, dtype=F64).expand(n, 3, 3), t)


def rig_trajectories(cam0: Tensor, extrinsics: Tensor, scales: Tensor | None = None) -> Tensor:
    """Every camera's trajectory, re-referenced to its own first frame.

    Args:
        cam0: (n, 4, 4) camera-0 poses. extrinsics: (K, 4, 4) ``T_cam0_camk``, or (n, K, 4, 4) one per frame (a
            camera that moves on the rig).
        scales: (K,) the scale of each camera's units (``s`` multiplies camera-k units into camera-0).

    Returns:
        (n, 1 + K, 4, 4) poses, camera 0 first.
    """
    extrinsics = extrinsics.expand(len(cam0), *extrinsics.shape[-3:])
    poses = cam0.unsqueeze(1) @ torch.cat([torch.eye(4, dtype=F64).expand(len(cam0), 1, 4, 4), extrinsics], 1)
    poses = rereference(poses.transpose(0, 1)).transpose(0, 1).clone()
    if scales is not None:
        poses[:, 1:, :3, 3] /= scales[None, :, None]
    return poses


def knocked(
    extrinsic: Tensor, frames: int, at: int, rotation_deg: tuple = (0.0, 2.0, 0.0), shift: tuple = (0.05, 0.0, 0.0)
) -> Tensor:
    """Per-frame ``T_cam0_camk`` (frames, 4, 4) of a camera knocked at frame ``at``: ``extrinsic`` (4, 4) before,
    then turned by the rotation vector ``rotation_deg`` (degrees, camera 0's axes) and moved by ``shift``."""
    new = make_pose(so3_exp(torch.deg2rad(torch.tensor(rotation_deg, dtype=F64))) @ extrinsic[:3, :3],
                    extrinsic[:3, 3] + torch.tensor(shift, dtype=F64))  # fmt: skip
    return torch.where((torch.arange(frames) < at)[:, None, None], extrinsic, new)


def add_noise(poses: Tensor, sigma: float, generator: torch.Generator, model: str = "independent") -> Tensor:
    """Gaussian pose noise of ``sigma`` (radians for rotation, units for translation).

    ``independent``: each pose perturbed on its own (the paper's simulation);
    ``drift``: each frame-to-frame motion perturbed and accumulated (visual odometry). Shape (n, ..., 4, 4).
    """
    if sigma == 0:
        return poses.clone()
    n = poses.shape[0]
    noise = make_pose(
        so3_exp(sigma * torch.randn(*poses.shape[:-2], 3, generator=generator, dtype=F64)),
        sigma * torch.randn(*poses.shape[:-2], 3, generator=generator, dtype=F64),
    )
    if model == "independent":
        return poses @ noise
    if model == "drift":
        steps = torch.linalg.inv(poses[:-1]) @ poses[1:]
        out = [poses[0]]
        for i in range(n - 1):
            out.append(out[-1] @ steps[i] @ noise[i + 1])
        return torch.stack(out)
    raise ValueError(f"noise model must be 'independent' or 'drift', got {model!r}")


def off_trajectory(poses: np.ndarray, degrees: float, seed: int = 0) -> np.ndarray:
    """``poses`` (T, 4, 4) as a real metric trajectory (GNSS/INS, odometry) has them: their rotation off by a random
    walk of ``degrees`` a frame (about each world axis, per square root of a frame), their positions by 1 cm of white
    noise per axis. Numpy, float64."""
    rng = np.random.default_rng(seed)
    walk = se3.so3_exp(np.cumsum(rng.normal(0, np.radians(degrees), (len(poses), 3)), axis=0))
    out = poses.copy()
    out[:, :3, :3] = walk @ poses[:, :3, :3]
    out[:, :3, 3] += rng.normal(0, 0.01, (len(poses), 3))
    return out
