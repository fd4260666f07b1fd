"""The motion distance: closed forms for known rotations and translations, a finite gradient where motions agree."""

import math

import pytest
import torch

from ocalib.geometry.pose import make_pose
from ocalib.geometry.quaternion import quaternion_to_rotation_matrix, rotation_angle
from ocalib.losses.motion import motion_distance


def _random_motion(n: int, dtype) -> torch.Tensor:
    q = torch.randn(n, 4, dtype=dtype)
    return make_pose(quaternion_to_rotation_matrix(q / q.norm(dim=-1, keepdim=True)), torch.randn(n, 3, dtype=dtype))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_motion_distance_against_closed_form(dtype):
    torch.manual_seed(0)
    T_ref = _random_motion(5, dtype)
    delta = _random_motion(5, dtype)  # a random rotation of the reference, a random translation offset
    T = T_ref.clone()
    T[:, :3, :3] = T_ref[:, :3, :3] @ delta[:, :3, :3]
    T[:, :3, 3] = T_ref[:, :3, 3] + delta[:, :3, 3]
    rotation, translation = motion_distance(T, T_ref, eps=0.0)
    angle = rotation_angle(delta[:, :3, :3])
    torch.testing.assert_close(rotation, torch.rad2deg(2 * torch.sin(angle / 2)), rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(translation, delta[:, :3, 3].norm(dim=-1) / T_ref[:, :3, 3].norm(dim=-1))


def test_motion_distance_small_rotation_is_its_angle():
    T_ref = torch.eye(4, dtype=torch.float64)[None]
    T = T_ref.clone()
    a = math.radians(1.5)
    T[0, :2, :2] = torch.tensor([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]], dtype=torch.float64)
    T_ref[0, 0, 3] = 2.0
    rotation, translation = motion_distance(T, T_ref)
    assert rotation.item() == pytest.approx(1.5, rel=1e-4)
    assert translation.item() == pytest.approx(1.0, rel=1e-5)


def test_motion_distance_gradient_finite_where_motions_agree_and_gradcheck():
    torch.manual_seed(1)
    T_ref = _random_motion(3, torch.float64)
    T = T_ref.clone().requires_grad_()
    rotation, translation = motion_distance(T, T_ref)
    assert rotation.abs().max() < 1e-12 and translation.abs().max() < 1e-12
    (rotation.sum() + translation.sum()).backward()
    assert torch.isfinite(T.grad).all()
    T2 = (T_ref + 0.01 * torch.randn_like(T_ref)).requires_grad_()
    assert torch.autograd.gradcheck(lambda x: torch.cat(motion_distance(x, T_ref)), (T2,))
