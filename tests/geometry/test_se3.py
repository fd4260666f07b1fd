"""The numpy rigid-motion helpers (ocalib.geometry.se3) against scipy's rotations, numpy's cross product and their
torch twins; and the numpy geometry importing no torch."""

import subprocess
import sys

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from ocalib.geometry.quaternion import rotation_angle
from ocalib.geometry.quaternion import so3_exp as torch_so3_exp
from ocalib.geometry.se3 import (
    chain_motions,
    cross_matrix,
    innovation,
    invert,
    perturbed,
    rotation_angle_deg,
    so3_exp,
    so3_log,
)


def test_cross_matrix_is_the_cross_product():
    a, b = np.random.default_rng(0).normal(size=(2, 5, 3))
    np.testing.assert_allclose(cross_matrix(a) @ b[..., None], np.cross(a, b)[..., None], atol=1e-12)


@pytest.mark.parametrize("angle", [0.0, 1e-9, 1e-4, 0.5, 1.6, 3.0, np.pi - 1e-7, np.pi])
def test_so3_exp_and_log_are_scipy_rotation_vectors_at_every_angle(angle):
    axis = np.random.default_rng(1).normal(size=3)
    w = axis / np.linalg.norm(axis) * angle
    R = so3_exp(w)
    np.testing.assert_allclose(R, Rotation.from_rotvec(w).as_matrix(), atol=1e-14)
    np.testing.assert_allclose(torch_so3_exp(torch.from_numpy(w)).numpy(), R, atol=1e-14)
    if angle < np.pi:  # at 180 degrees w and -w are the same rotation
        np.testing.assert_allclose(so3_log(R), w, atol=1e-9)
    assert rotation_angle_deg(R) == pytest.approx(np.degrees(angle), abs=1e-9)
    assert rotation_angle(torch.from_numpy(R)).item() == pytest.approx(angle, abs=1e-9)


def test_so3_exp_and_log_are_batched():
    w = np.random.default_rng(2).normal(size=(4, 5, 3))
    R = so3_exp(w)
    assert R.shape == (4, 5, 3, 3)
    np.testing.assert_allclose(so3_log(R), Rotation.from_matrix(R.reshape(-1, 3, 3)).as_rotvec().reshape(4, 5, 3))


def test_perturbed_inverts_innovation_on_the_left():
    rng = np.random.default_rng(3)
    reference, d = np.eye(4), rng.normal(size=6) * 0.3
    reference[:3, :3], reference[:3, 3] = so3_exp(rng.normal(size=3)), rng.normal(size=3)
    estimate = perturbed(reference, d)
    np.testing.assert_allclose(estimate[:3, :3], so3_exp(d[:3]) @ reference[:3, :3], atol=1e-14)
    np.testing.assert_allclose(innovation(reference, estimate), d, atol=1e-12)


def test_invert_and_chain_motions():
    rng = np.random.default_rng(4)
    motions = np.tile(np.eye(4), (3, 1, 1))
    motions[:, :3, :3], motions[:, :3, 3] = so3_exp(rng.normal(size=(3, 3))), rng.normal(size=(3, 3))
    np.testing.assert_allclose(invert(motions) @ motions, np.tile(np.eye(4), (3, 1, 1)), atol=1e-12)
    poses = chain_motions(motions)
    np.testing.assert_allclose(invert(poses[:-1]) @ poses[1:], motions, atol=1e-12)


@pytest.mark.parametrize(
    "module", ["ocalib.geometry.se3", "ocalib.geometry.alignment", "ocalib.geometry.directions", "ocalib.geometry"]
)
def test_the_numpy_geometry_imports_no_torch(module):
    code = f"import sys, {module}; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"
