import pytest
import torch
from calib_helpers import lds_rig

from ocalib.calib.handeye import rotation_block
from ocalib.calib.linalg import guarded_eigh
from ocalib.calib.rotation import batch_rotation, incremental_svd_update, rotation_solution, singular_values
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
