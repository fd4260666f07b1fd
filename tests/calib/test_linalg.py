"""The small linear algebra's compiled twins (and the quaternion functions')."""

import numpy as np
import pytest
import torch
from calib_helpers import random_orthonormal, random_rotations

from ocalib.calib.stages import linalg_kernel
from ocalib.geometry import left_product_matrix, quaternion_to_rotation_matrix, rotation_matrix_to_quaternion


@pytest.mark.parametrize("n", [4, 6])
def test_eigh_twins(generator, n):
    """Distinct, repeated and zero eigenvalues: the same eigenvalues, and eigenvectors that span the same matrix."""
    evals = torch.randn(4, n, generator=generator, dtype=torch.float64).abs()
    evals[1, :2], evals[2, 1:3], evals[3, : n // 2] = 0.0, 1.0, 0.0
    V = random_orthonormal(generator, 4, n=n)
    A = (V * evals[:, None]) @ V.mT
    want = torch.linalg.eigvalsh(A)
    for a, w_ref in zip(A.numpy(), want.numpy()):
        evals, evecs = np.empty((2, n)), np.empty((2, n, n))
        linalg_kernel.eigh(a, n, evals[0], evecs[0], np.empty((n, n)))
        if n == 4:
            linalg_kernel.eigh4(a, evals[1], evecs[1], np.empty((n, n)))
        for w, E in zip(evals[: 1 + (n == 4)], evecs):
            np.testing.assert_allclose(w, w_ref, rtol=0, atol=1e-13 * w_ref.max())
            np.testing.assert_allclose(E.T @ E, np.eye(n), rtol=0, atol=1e-13)
            np.testing.assert_allclose((E * w) @ E.T, a, rtol=0, atol=1e-13 * w_ref.max())


def test_lu_solve_twin(generator):
    H = torch.randn(5, 7, 7, generator=generator, dtype=torch.float64)
    b = torch.randn(5, 7, generator=generator, dtype=torch.float64)
    want = torch.linalg.solve(H, b)
    for i in range(len(H)):
        x = np.empty(7)
        linalg_kernel.lu_solve(H[i].numpy().copy(), b[i].numpy().copy(), 7, x)
        np.testing.assert_allclose(x, want[i].numpy(), rtol=1e-10, atol=1e-12)


def test_quaternion_twins(generator):
    """Every pivot of Shepperd's method: rotations of all angles, 180 degrees included."""
    R = torch.cat(
        [random_rotations(generator, 20), torch.diag(torch.tensor([1.0, -1.0, -1.0], dtype=torch.float64))[None]]
    )
    q = rotation_matrix_to_quaternion(R)
    for i in range(len(R)):
        got_q, got_R, got_L = np.empty(4), np.empty((3, 3)), np.empty((4, 4))
        linalg_kernel.rotation_matrix_to_quaternion(R[i].numpy(), got_q)
        linalg_kernel.quaternion_to_rotation_matrix(2.0 * q[i].numpy(), got_R)  # any norm
        linalg_kernel.left_product_matrix(q[i].numpy(), got_L)
        np.testing.assert_allclose(got_q, q[i].numpy(), rtol=0, atol=1e-15)
        np.testing.assert_allclose(got_R, quaternion_to_rotation_matrix(q[i]).numpy(), rtol=0, atol=1e-15)
        np.testing.assert_array_equal(got_L, left_product_matrix(q[i]).numpy())
