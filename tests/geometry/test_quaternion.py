import kornia.geometry.conversions as kc
import pytest
import torch

from ocalib.geometry import (
    canonical_quaternion,
    left_product_matrix,
    orthonormality_error,
    quaternion_angle,
    quaternion_conjugate,
    quaternion_multiply,
    quaternion_to_rotation_matrix,
    right_product_matrix,
    rotation_angle,
    rotation_matrix_to_quaternion,
)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_matches_kornia(dtype, device, generator):
    q = canonical_quaternion(torch.randn(500, 4, generator=generator, dtype=torch.float64)).to(dtype).to(device)
    q = q / q.norm(dim=-1, keepdim=True)
    R = quaternion_to_rotation_matrix(q)
    tol = 1e-5 if dtype == torch.float32 else 1e-12
    torch.testing.assert_close(R, kc.quaternion_to_rotation_matrix(q), atol=tol, rtol=0)
    torch.testing.assert_close(rotation_matrix_to_quaternion(R), q, atol=tol * 10, rtol=0)
    assert orthonormality_error(R).max() < tol * 10


def test_shepperd_near_180_degrees(generator):
    axis = torch.randn(100, 3, generator=generator, dtype=torch.float64)
    axis = axis / axis.norm(dim=-1, keepdim=True)
    angle = torch.pi - torch.rand(100, 1, generator=generator, dtype=torch.float64) * 1e-6
    q = torch.cat([torch.cos(angle / 2), torch.sin(angle / 2) * axis], -1)
    R = quaternion_to_rotation_matrix(q)
    torch.testing.assert_close(quaternion_to_rotation_matrix(rotation_matrix_to_quaternion(R)), R, atol=1e-12, rtol=0)
    torch.testing.assert_close(rotation_angle(R), angle[:, 0], atol=1e-9, rtol=0)
    torch.testing.assert_close(quaternion_angle(q), angle[:, 0], atol=1e-9, rtol=0)


def test_product_matrices(generator):
    p, q = torch.randn(2, 50, 4, generator=generator, dtype=torch.float64)
    pq = quaternion_multiply(p, q)
    torch.testing.assert_close((right_product_matrix(q) @ p[..., None])[..., 0], pq)
    # Hamilton product against rotation composition: R(p q) = R(p) R(q).
    torch.testing.assert_close(
        quaternion_to_rotation_matrix(pq), quaternion_to_rotation_matrix(p) @ quaternion_to_rotation_matrix(q)
    )
    torch.testing.assert_close(left_product_matrix(p) @ q[..., None], pq[..., None])


def test_conjugate_inverts_the_rotation(generator, device):
    q = torch.randn(50, 4, generator=generator, dtype=torch.float64).to(device)
    q = q / q.norm(dim=-1, keepdim=True)
    torch.testing.assert_close(
        quaternion_to_rotation_matrix(quaternion_conjugate(q)), quaternion_to_rotation_matrix(q).mT
    )
    torch.testing.assert_close(
        kc.quaternion_to_rotation_matrix(quaternion_conjugate(q)), kc.quaternion_to_rotation_matrix(q).mT
    )


def test_gradcheck(generator):
    q = torch.randn(3, 4, generator=generator, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda q: rotation_matrix_to_quaternion(quaternion_to_rotation_matrix(q)), (q,))
