import numpy as np
import pytest
import torch
from calib_helpers import lds_rig, random_orthonormal, random_rotations

from ocalib.calib.stages import rotation_kernel
from ocalib.calib.stages.handeye import rotation_block, rotation_blocks
from ocalib.calib.stages.linalg import guarded_eigh
from ocalib.calib.stages.rotation import (
    RotationSystem,
    batch_rotation,
    incremental_svd_update,
    rotation_gram,
    rotation_solution,
    singular_values,
    update_rotation_system,
)
from ocalib.geometry import invert_pose, rotation_matrix_to_quaternion


def blocks(generator, frames=60, noise=0.02):
    poses, X, _ = lds_rig(generator, frames=frames, noise=noise)
    motion = invert_pose(poses[:1]) @ poses[1:]
    q = rotation_matrix_to_quaternion(motion[..., :3, :3])
    return rotation_block(q[:, 0], q[:, 1]), X


@pytest.mark.parametrize("forgetting", [1.0, 0.9])
def test_incremental_svd_equals_batch_svd_every_frame(generator, forgetting):
    A, _ = blocks(generator)
    S, V = torch.zeros(4, dtype=torch.float64), torch.eye(4, dtype=torch.float64)
    for t in range(len(A)):
        S, V = incremental_svd_update(S, V, A[t], forgetting)
        weights = forgetting ** torch.arange(t, -1, -1, dtype=torch.float64)
        dq_ref, S_ref, _ = batch_rotation(A[: t + 1], weights)
        torch.testing.assert_close(singular_values(S), S_ref, atol=1e-8, rtol=0)
        if t >= 2:  # from the third motion on, the null vector is unique
            torch.testing.assert_close(rotation_solution(V), dq_ref, atol=1e-8, rtol=0)


def test_noise_free_solution_is_the_extrinsic(generator):
    A, X = blocks(generator, noise=0.0)
    S, V = torch.zeros(4, dtype=torch.float64), torch.eye(4, dtype=torch.float64)
    for t in range(len(A)):
        S, V = incremental_svd_update(S, V, A[t])
    torch.testing.assert_close(rotation_solution(V), rotation_matrix_to_quaternion(X[0, :3, :3]), atol=1e-10, rtol=0)


def test_gradcheck_incremental_update(generator):
    A, _ = blocks(generator, frames=8)
    W = A[-1].clone().requires_grad_()
    S0, V0 = torch.zeros(4, dtype=torch.float64), torch.eye(4, dtype=torch.float64)
    for t in range(len(A) - 1):
        S0, V0 = incremental_svd_update(S0, V0, A[t])

    def f(W):
        S2, V = incremental_svd_update(S0, V0, W)
        return S2, rotation_solution(V)

    assert torch.autograd.gradcheck(f, (W,))


def test_guarded_gradients_on_repeated_eigenvalues():
    M = torch.diag(torch.tensor([0.0, 0.0, 1.0, 1.0], dtype=torch.float64)).requires_grad_()
    evals, evecs = guarded_eigh(M)
    (evecs[:, 0].sum() + evals.sum()).backward()
    assert torch.isfinite(M.grad).all()
    # torch's own eigh gives non-finite gradients here, which is why the guard exists.
    M2 = M.detach().clone().requires_grad_()
    e2, v2 = torch.linalg.eigh(M2)
    (v2[:, 0].sum() + e2.sum()).backward()
    assert not torch.isfinite(M2.grad).all()


@pytest.mark.parametrize("forgetting", [1.0, 0.9])
def test_update_rotation_system_twin(generator, forgetting):
    """Each gap's system, from nothing (repeated zero singular values) and from earlier rows; weights 0 to 1."""
    B, P = 4, 5
    S2 = (10 * torch.rand(B, P, 4, generator=generator, dtype=torch.float64)).sort(-1, descending=True).values
    S2[0] = 0.0
    V = random_orthonormal(generator, B, P)
    V[0] = torch.eye(4, dtype=torch.float64)
    system = RotationSystem(S2, V, 20 * torch.rand(B, P, generator=generator, dtype=torch.float64))
    A = rotation_blocks(rotation_matrix_to_quaternion(random_rotations(generator, B, 2, P)))[:, 0]  # (B, P, 4, 4)
    weight = torch.rand(B, P, generator=generator, dtype=torch.float64)
    weight[:, 0] = 0.0
    want = update_rotation_system(system, A, weight, forgetting)
    for b in range(B):
        got = RotationSystem(*(x[b].numpy().copy() for x in system))
        rotation_kernel.update_rotation_system(
            got, A[b].numpy(), weight[b].numpy(), forgetting, rotation_kernel.workspace()
        )
        np.testing.assert_allclose(got.rotation_rows, want.rotation_rows[b].numpy(), rtol=1e-14)
        np.testing.assert_allclose(got.S2, want.S2[b].numpy(), rtol=0, atol=1e-12 * want.S2[b].max().item())
        M = rotation_gram(torch.from_numpy(got.S2), torch.from_numpy(got.V))
        torch.testing.assert_close(
            M, rotation_gram(want.S2[b], want.V[b]), rtol=0, atol=1e-12 * want.S2[b].max().item()
        )
