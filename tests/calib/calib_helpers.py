"""Shared test data: simulated rigs with known extrinsics."""

import torch

from ocalib.calib.drivers.online import OnlineCalibrator
from ocalib.calib.stages.gating import NO_GATES
from ocalib.calib.stages.handeye import TranslationMoment, row_statistics, translation_quadratic
from ocalib.calib.stages.rotation import RotationSystem
from ocalib.geometry import make_pose
from ocalib.geometry.quaternion import so3_exp
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
    return dict(gates=NO_GATES, **kw)


def random_rotations(generator, *shape):
    """Random rotation matrices (*shape, 3, 3), angles up to about 100 degrees."""
    return so3_exp(torch.randn(*shape, 3, generator=generator, dtype=torch.float64))


def random_poses(generator, *shape, scale=1.0):
    """Random camera-to-world poses (*shape, 4, 4), translations of about ``scale``."""
    t = scale * torch.randn(*shape, 3, generator=generator, dtype=torch.float64)
    return make_pose(random_rotations(generator, *shape), t)


def random_orthonormal(generator, *shape, n=4):
    """Random orthonormal matrices (*shape, n, n)."""
    return torch.linalg.qr(torch.randn(*shape, n, n, generator=generator, dtype=torch.float64))[0]


def random_moment(generator, *shape, rows=20):
    """Random translation statistics (*shape, 58): those of ``rows`` random feature vectors."""
    z = torch.randn(*shape, rows, 15, generator=generator, dtype=torch.float64)
    return row_statistics(z).sum(-2)


def stream_statistics(poses, **options):
    """The statistics the PyTorch head keeps after every frame of ``poses`` (T, B, C, 4, 4), stacked (T, B, K, ...):
    the combined rotation system (RotationSystem) and translation moment (TranslationMoment)."""
    head = OnlineCalibrator(poses.shape[2], poses.shape[1], backend="torch", **options)
    out = [head(p) for p in poses]
    S2 = torch.stack([o.rotation_singular_values for o in out]).square()
    rotation = RotationSystem(
        S2, torch.stack([o.rotation_basis for o in out]), torch.stack([o.rotation_rows for o in out])
    )
    moment = (torch.stack([getattr(o, name) for o in out]) for name in ("translation_moment", "translation_rows",
                                                                         "translation_moment_reverse"))  # fmt: skip
    return rotation, TranslationMoment(*moment)


def head_statistics(generator, frames=40):
    """The statistics of the PyTorch head after each frame of two noisy rigs and a car's (planar motion), flattened
    (N, ...): the rotation system, the translation moment's quadratic form, its row count and the quadratic form of
    its reverse rows."""
    rigs = torch.stack([lds_rig(generator, frames=frames, noise=0.01)[0] for _ in range(2)], 1)
    car = car_rig(generator, frames=frames, noise=0.002)[0][:, None]
    (rotation_a, moment_a), (rotation_b, moment_b) = stream_statistics(rigs), stream_statistics(car)

    def join(a, b):
        return torch.cat([a, b], 1).flatten(0, 2)

    Z, rows, Z_reverse = map(join, moment_a, moment_b)
    rotation = RotationSystem(*map(join, rotation_a, rotation_b))
    return rotation, translation_quadratic(Z), rows, translation_quadratic(Z_reverse)


def entry(quantities, i):
    """Entry ``i`` of batched tensors (a tuple of them) as numpy arrays or, where 0-d, floats, for a compiled twin."""
    return tuple(float(x[i]) if x.dim() == 1 else x[i].numpy() for x in quantities)
