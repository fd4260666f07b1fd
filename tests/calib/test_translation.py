import numpy as np
import pytest
import torch
from calib_helpers import lds_rig, random_moment, random_rotations

from ocalib.calib import translation_kernel
from ocalib.calib.handeye import translation_features, translation_quadratic, translation_rows
from ocalib.calib.translation import pinv_solve, rls_update, solve_translation
from ocalib.geometry import invert_pose


def rows(generator, noise=0.02, frames=60):
    poses, X, s = lds_rig(generator, frames=frames, noise=noise)
    motion = invert_pose(poses[:-1]) @ poses[1:]
    R0, t0, t1 = motion[:, 0, :3, :3], motion[:, 0, :3, 3], motion[:, 1, :3, 3]
    return R0, t0, t1, X[0, :3, :3]


def test_exact_solver_equals_batch_least_squares_every_frame(generator):
    R0, t0, t1, dR = rows(generator)
    z = translation_features(R0, t0, t1)
    B, b = translation_rows(R0, t0, t1, dR)
    Z = torch.zeros(15, 15, dtype=torch.float64)
    for t in range(len(z)):
        Z = Z + z[t, :, None] * z[t, None, :]
        x = solve_translation(translation_quadratic(Z), dR)
        if t >= 2:
            ref = torch.linalg.lstsq(B[: t + 1].reshape(-1, 4), b[: t + 1].reshape(-1, 1)).solution[:, 0]
            torch.testing.assert_close(x, ref, atol=1e-8, rtol=0)


def test_rls_equals_ridge_batch_every_frame(generator):
    R0, t0, t1, dR = rows(generator)
    B, b = translation_rows(R0, t0, t1, dR)
    c0 = 1.0  # the paper's C0 = I: RLS is exactly least squares with the prior x ~ N(0, C0)
    x, C = torch.zeros(4, dtype=torch.float64), c0 * torch.eye(4, dtype=torch.float64)
    for t in range(len(B)):
        x, C = rls_update(x, C, B[t], b[t])
        Bs, bs = B[: t + 1].reshape(-1, 4), b[: t + 1].reshape(-1)
        ref = torch.linalg.solve(Bs.T @ Bs + torch.eye(4, dtype=torch.float64) / c0, Bs.T @ bs)
        torch.testing.assert_close(x, ref, atol=1e-8, rtol=0)


def test_rls_with_large_c0_equals_batch_least_squares(generator):
    R0, t0, t1, dR = rows(generator)
    B, b = translation_rows(R0, t0, t1, dR)
    c0 = 1e9
    eye = torch.eye(4, dtype=torch.float64)
    x, C = torch.zeros(4, dtype=torch.float64), c0 * eye
    for t in range(len(B)):
        x, C = rls_update(x, C, B[t], b[t])
        Bs, bs = B[: t + 1].reshape(-1, 4), b[: t + 1].reshape(-1)
        # Every frame: equal to batch least squares with the same prior (its exact equivalent) ...
        torch.testing.assert_close(x, torch.linalg.solve(Bs.T @ Bs + eye / c0, Bs.T @ bs), atol=1e-8, rtol=0)
        # ... whose ridge bias (~1 / (C0 * information)) falls below 1e-8 once a few dozen frames are in.
        if t >= 30:
            ref = torch.linalg.lstsq(Bs, bs[:, None]).solution[:, 0]
            torch.testing.assert_close(x, ref, atol=1e-8, rtol=0)


@pytest.mark.parametrize("forgetting", [0.95, 0.8])
def test_rls_forgetting_equals_weighted_batch(generator, forgetting):
    R0, t0, t1, dR = rows(generator)
    B, b = translation_rows(R0, t0, t1, dR)
    c0 = 10.0
    x, C = torch.zeros(4, dtype=torch.float64), c0 * torch.eye(4, dtype=torch.float64)
    for t in range(len(B)):
        x, C = rls_update(x, C, B[t], b[t], forgetting)
    n = len(B)
    w = forgetting ** torch.arange(n - 1, -1, -1, dtype=torch.float64)
    H = torch.einsum("t,tri,trj->ij", w, B, B) + forgetting**n * torch.eye(4, dtype=torch.float64) / c0
    g = torch.einsum("t,tri,tr->i", w, B, b)
    torch.testing.assert_close(x, torch.linalg.solve(H, g), atol=1e-8, rtol=0)


def test_solve_translation_twin(generator):
    Z, dR = random_moment(generator, 4), random_rotations(generator, 4)
    want = solve_translation(translation_quadratic(Z), dR)
    for b in range(len(Z)):
        x = np.empty(4)
        P, p, c = translation_quadratic(Z[b])
        quadratic = (P.numpy(), p.numpy(), float(c))
        translation_kernel.solve_translation(quadratic, dR[b].numpy(), x, translation_kernel.workspace())
        np.testing.assert_allclose(x, want[b].numpy(), rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("solve", [translation_kernel.pinv_solve, translation_kernel.spd_solve])
def test_minimum_norm_solve_twins_on_rank_deficient_systems(generator, solve):
    """Cholesky gives way to the eigen-decomposition's pseudo-inverse where a direction is (nearly) free."""
    J = torch.randn(4, 6, 3, generator=generator, dtype=torch.float64)
    H = J @ J.mT  # rank 3
    H[1] += 1e-12 * torch.eye(6, dtype=torch.float64)  # positive definite, but beyond the rank tolerance
    H[2] = torch.eye(6, dtype=torch.float64) + H[2]  # well conditioned: Cholesky's
    g = (H @ torch.randn(4, 6, 1, generator=generator, dtype=torch.float64)).squeeze(-1)
    want = pinv_solve(H, g)[0]
    for b in range(len(H)):
        x = np.empty(6)
        solve(H[b].numpy(), g[b].numpy(), 6, x, translation_kernel.workspace())
        np.testing.assert_allclose(x, want[b].numpy(), rtol=1e-9, atol=1e-9)
