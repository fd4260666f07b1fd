"""Shared test data: simulated rigs with known extrinsics."""

import torch

from ocalib.sim.trajectory import add_noise, car_trajectory, lds_trajectory, random_rig, rig_trajectories


def lds_rig(generator, frames=64, cameras=2, noise=0.0, scale=2.0, model="independent"):
    """(poses (T, C, 4, 4), extrinsics (K, 4, 4), scales (K,))."""
    X = torch.stack([random_rig(generator) for _ in range(cameras - 1)])
    s = torch.full((cameras - 1,), scale, dtype=torch.float64)
    poses = rig_trajectories(lds_trajectory(frames, generator), X, s)
    return add_noise(poses, noise, generator, model), X, s


def car_rig(generator, frames=200, noise=0.0, pitch_roll=0.0):
    X = random_rig(generator)[None]
    poses = rig_trajectories(car_trajectory(frames, generator, pitch_roll=pitch_roll), X)
    return add_noise(poses, noise, generator), X


def no_gating(**kw):
    return dict(screw_gate_deg=1e9, min_rotation_deg=0.0, robust_deg=1e9, **kw)
