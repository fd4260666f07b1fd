"""ocalib.eval.calibration_metrics.scale_wander against closed forms on synthetic car rigs (ocalib.sim)."""

import math

import numpy as np
import pytest
import torch

from ocalib.eval.calibration_metrics import scale_wander
from ocalib.geometry.pose import make_pose
from ocalib.geometry.quaternion import so3_exp
from ocalib.sim.trajectory import car_trajectory, rig_trajectories


def car_rig(lever_arm: bool) -> np.ndarray:
    """(300, 2, 4, 4) true poses of a car rig with a camera looking left, beside camera 0 or at its place."""
    left = make_pose(
        so3_exp(torch.tensor([0.0, -math.pi / 2, 0.0], dtype=torch.float64)),
        torch.tensor([-0.8, 0.0, -1.1] if lever_arm else [0.0, 0.0, 0.0], dtype=torch.float64),
    )
    return rig_trajectories(car_trajectory(300, torch.Generator().manual_seed(0)), left[None]).numpy()


def with_step_scale(poses: np.ndarray, factor: np.ndarray) -> np.ndarray:
    """The trajectory (T, 4, 4) with step t's translation multiplied by factor[t] (T - 1,)."""
    steps = np.linalg.inv(poses[:-1]) @ poses[1:]
    steps[:, :3, 3] *= factor[:, None]
    out = [np.eye(4)]
    for step in steps:
        out.append(out[-1] @ step)
    return np.stack(out)


def test_a_constant_scale_does_not_wander_and_the_lever_arm_is_the_signal():
    truth = car_rig(lever_arm=True)
    front_end = truth.copy()
    front_end[:, 1] = with_step_scale(truth[:, 1], np.full(299, 3.0))  # camera 1 in other units
    wander, signal = scale_wander(front_end, truth)
    assert wander < 1e-9 and signal > 0.01
    together = car_rig(lever_arm=False)  # both cameras at one place step alike
    assert scale_wander(together, together)[1] < 1e-9


@pytest.mark.parametrize("period", [100, 150])
def test_a_sinusoidal_scale_wanders_by_its_closed_form(period):
    """log-scale a sin(2 pi t / P) on camera 1: the W-frame moving mean of a sinusoid keeps
    |sin(pi W / P) / (W sin(pi / P))| of its amplitude, and a sinusoid's std is amplitude / sqrt(2)."""
    truth = car_rig(lever_arm=False)
    a, W = 0.1, 25
    front_end = truth.copy()
    front_end[:, 1] = with_step_scale(truth[:, 1], np.exp(a * np.sin(2 * np.pi * np.arange(299) / period)))
    wander, _ = scale_wander(front_end, truth, window=W)
    expected = a / math.sqrt(2) * abs(math.sin(math.pi * W / period) / (W * math.sin(math.pi / period)))
    assert wander == pytest.approx(expected, rel=0.05)


def test_too_few_moving_frames_give_nan_and_lost_frames_are_left_out():
    truth = car_rig(lever_arm=True)
    assert all(math.isnan(x) for x in scale_wander(truth[:40], truth[:40]))
    assert all(math.isnan(x) for x in scale_wander(truth[:1].repeat(300, 0), truth[:1].repeat(300, 0)))  # static
    lost = truth.copy()
    lost[100:110, 1] = np.nan  # a front end that lost camera 1 for ten frames
    wander, signal = scale_wander(lost, truth)
    assert wander < 1e-9 and signal == pytest.approx(scale_wander(truth, truth)[1], rel=0.1)


def test_projector_without_leaves_the_complement_of_the_directions_given():
    """Against hand-built projectors: none given is the identity; one unit row u gives I - u u^T; a second row 5 deg
    from the first is the same direction (a car's unobservable height and its ground normal), while two orthogonal
    rows leave one axis; NaN rows are ignored."""
    from ocalib.geometry.directions import projector_without

    y = np.array([0.0, 1.0, 0.0])
    assert np.allclose(projector_without(np.zeros((0, 3))), np.eye(3))
    assert np.allclose(projector_without(y[None]), np.eye(3) - np.outer(y, y))
    near = np.array([np.sin(np.radians(5)), np.cos(np.radians(5)), 0.0])
    P = projector_without(np.stack([y, near]))
    assert np.linalg.matrix_rank(P) == 2 and np.allclose(P @ P, P) and np.allclose(P, P.T)
    assert np.linalg.norm(P @ y) < np.sin(np.radians(5))
    assert np.allclose(projector_without(np.stack([y, [1.0, 0, 0], [np.nan] * 3])), np.diag([0.0, 0, 1]))
