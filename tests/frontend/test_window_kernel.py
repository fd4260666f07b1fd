"""The window bundle adjustment's compiled per-iteration work against its numpy reference (kept here): the same
floating-point values to the last bit, so the VO's trajectories do not move by a bit.

The reference is numpy products as the adjustment first computed them: matrix products through numpy's BLAS, the
einsum contractions, the two-term products written out and sparse summing products. The kernel rounds as OpenBLAS's
double-precision kernels for x86-64 with FMA do (each product of small matrices a chain of fused multiply-adds); where
numpy's BLAS rounds otherwise (another library or CPU), the two agree to rounding only, and that is what is checked.
"""

import cv2
import numpy as np
import pytest
from scipy import sparse

import ocalib.frontend.window as window
from ocalib.frontend.window import bundle_adjust, window_problem
from ocalib.frontend.window_kernel import _gemm, normal_equations, project
from ocalib.geometry.se3 import cross_matrix

K = np.array([[718.856, 0, 607.1928], [0, 718.856, 185.2157], [0, 0, 1]])


def _inner(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A^T B`` (M, p, q) of A (M, 2, p) and B (M, 2, q), its two terms written out."""
    out = A[:, 0, :, None] * B[:, 0, None, :]
    out += A[:, 1, :, None] * B[:, 1, None, :]
    return out if B.shape[2] > 1 else out[..., 0]


def _summing(keys: list[np.ndarray], size: int) -> sparse.csr_matrix:
    """The sparse (size, N) matrix that sums rows (N, D) of arrays stacked in the order of ``keys`` (each (M,)) by
    their keys, each sum in the rows' order."""
    keys = np.concatenate(keys)
    return sparse.csr_matrix((np.ones(len(keys)), (keys, np.arange(len(keys)))), shape=(size, len(keys)))


def reference_project(R, cen, rho, frame, landmark, a, b, K, pixels):
    """numpy reference of :func:`~ocalib.frontend.window_kernel.project`."""
    Ra, ca, Rk, ck = R[a], cen[a], R[frame], cen[frame]
    Y = np.einsum("mji,mj->mi", Rk, np.einsum("mij,mj->mi", Ra, b) + rho[landmark][:, None] * (ca - ck))
    z = np.where(np.abs(Y[:, 2]) > 1e-9, Y[:, 2], 1e-9)
    return Y, np.stack([K[0, 0] * Y[:, 0] / z + K[0, 2], K[1, 1] * Y[:, 1] / z + K[1, 2]], 1) - pixels


def reference_normal_equations(R, cen, rho, frame, landmark, a, b, K, Y, r, c, F):
    """numpy reference of :func:`~ocalib.frontend.window_kernel.normal_equations`: the Jacobians of all
    observations at once, the normal equations summed by sparse products (the observing frames' rows, then the
    anchors')."""
    L, M = len(rho), len(frame)
    sides = (frame, a)
    sum_g, sum_pl = _summing(list(sides), F), _summing([f * L + landmark for f in sides], F * L)
    sum_b = _summing([f * F + f2 for f in sides for f2 in sides], F * F)
    z = Y[:, 2]
    P = np.zeros((M, 2, 3))  # d pixel / d Y
    P[:, 0, 0], P[:, 0, 2] = K[0, 0] / z, -K[0, 0] * Y[:, 0] / z**2
    P[:, 1, 1], P[:, 1, 2] = K[1, 1] / z, -K[1, 1] * Y[:, 1] / z**2
    PRkT = P @ np.swapaxes(R[frame], 1, 2)
    J_rho = PRkT @ (cen[a] - cen[frame])[..., None]  # (M, 2, 1)
    J_k = np.concatenate([P @ cross_matrix(Y), -rho[landmark, None, None] * PRkT], 2)  # observing frame
    J_a = np.concatenate([-(PRkT @ R[a] @ cross_matrix(b)), rho[landmark, None, None] * PRkT], 2)  # anchor
    w = 1.0 / (1.0 + (r * r).sum(1) / (c * c))
    Js, wr = (J_k, J_a), w[:, None] * r
    Jw = [J * w[:, None, None] for J in Js]
    gb = sum_g @ np.concatenate([_inner(J, wr[..., None]) for J in Js])
    Hpl = (sum_pl @ np.concatenate([_inner(Jwi, J_rho) for Jwi in Jw])).reshape(F, L, 6)
    Hb = (sum_b @ np.concatenate([_inner(Jwi, J).reshape(M, 36) for Jwi in Jw for J in Js])).reshape(F, F, 6, 6)
    Hll = np.bincount(landmark, w * (J_rho[:, :, 0] ** 2).sum(1), L)
    gl = np.bincount(landmark, w * (J_rho[:, :, 0] * r).sum(1), L)
    return gb, Hpl, Hb, Hll, gl


def _blas_rounds_as_kernel() -> bool:
    """Whether numpy's products of small matrices round as the kernel's (OpenBLAS's FMA kernels)."""
    rng = np.random.default_rng(7)
    A, B = rng.normal(size=(200, 2, 3)), rng.normal(size=(200, 3, 3))
    out = np.empty((2, 3))
    for m in range(len(A)):
        _gemm(A[m], B[m], out)
        if not np.array_equal(out, A[m] @ B[m]):
            return False
    return True


EXACT = _blas_rounds_as_kernel()


def _assert_same(actual, expected):
    """Bitwise equal (signs of zeros included) where numpy's BLAS rounds as the kernel, else equal to rounding."""
    actual, expected = np.asarray(actual), np.asarray(expected)
    if EXACT:
        np.testing.assert_array_equal(actual, expected)
        np.testing.assert_array_equal(np.signbit(actual), np.signbit(expected))
    else:
        np.testing.assert_allclose(actual, expected, rtol=1e-9, atol=1e-9 * np.abs(expected).max())


def _pose(rvec, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.asarray(rvec, float))[0]
    T[:3, 3] = t
    return T


@pytest.fixture
def problem():
    """A window of 8 frames along a road (frame 0 the identity: many exact zeros), tracks seen by 80 % of them,
    pixels with noise and 5 % outliers, the later poses perturbed: the arguments of :func:`bundle_adjust`."""
    rng = np.random.default_rng(4)
    points = np.stack([rng.uniform(-8, 8, 400), rng.uniform(-3, 1.5, 400), rng.uniform(4, 60, 400)], 1)
    poses = np.stack([_pose([0.01 * i, 0.02 * i, -0.005 * i], [0.05 * i, 0.01 * i, 0.8 * i]) for i in range(8)])
    history = []
    for f, pose in enumerate(poses):
        seen = np.flatnonzero(rng.random(len(points)) < 0.8)
        inv = np.linalg.inv(pose)
        p = points[seen] @ inv[:3, :3].T + inv[:3, 3]
        px = np.stack([K[0, 0] * p[:, 0] / p[:, 2] + K[0, 2], K[1, 1] * p[:, 1] / p[:, 2] + K[1, 2]], 1)
        px += rng.normal(0, 0.5, px.shape) + (rng.random((len(px), 1)) < 0.05) * rng.normal(0, 30, px.shape)
        history.append((f, seen, px))
    ids, frame, landmark, px, anchor, bearing, rho = window_problem(history, poses, K)
    noisy = poses.copy()
    for f in range(2, len(poses)):
        noisy[f] = noisy[f] @ _pose(rng.normal(0, 0.01, 3), rng.normal(0, 0.05, 3))
    return noisy, 2, frame, landmark, px, anchor, bearing, rho, K, 2.0


def test_window_sums_equal_add_at_to_the_last_bit():
    """The reference's normal equations are summed by a sparse product in the observations' order: the same
    floating-point sums as ``np.add.at``."""
    rng = np.random.default_rng(3)
    keys = [rng.integers(0, 7, 500), rng.integers(0, 7, 300)]
    values = [rng.normal(size=(500, 36)) * 10.0 ** rng.integers(-8, 8, (500, 1)), rng.normal(size=(300, 36))]
    expected = np.zeros((9, 36))
    for k, v in zip(keys, values):
        np.add.at(expected, k, v)
    np.testing.assert_array_equal(_summing(keys, 9) @ np.concatenate(values), expected)
    A, B = rng.normal(size=(50, 2, 6)), rng.normal(size=(50, 2, 6))
    np.testing.assert_array_equal(_inner(A, B), np.einsum("mip,miq->mpq", A, B))


def test_kernel_equals_numpy_reference(problem):
    """Projection, residuals and every sum of the normal equations, at the start and after the adjustment."""
    poses, fixed, frame, landmark, px, anchor, bearing, rho, K, c = problem
    a, b = anchor[landmark], np.ascontiguousarray(bearing[landmark])
    adjusted = bundle_adjust(*problem)
    for P, rh in ((poses, rho), adjusted[:2]):
        R, cen = P[:, :3, :3].copy(), P[:, :3, 3].copy()
        Y, r = reference_project(R, cen, rh, frame, landmark, a, b, K, px)
        for x, y in zip(project(R, cen, rh, frame, landmark, a, b, K, px), (Y, r)):
            _assert_same(x, y)
        expected = reference_normal_equations(R, cen, rh, frame, landmark, a, b, K, Y, r, c, len(P))
        for x, y in zip(normal_equations(R, cen, rh, frame, landmark, a, b, K, Y, r, c, len(P)), expected):
            _assert_same(x, y)


def test_bundle_adjust_equals_numpy_reference(problem, monkeypatch):
    """The whole adjustment (every Levenberg-Marquardt step) with the kernel and with the numpy reference."""
    compiled = bundle_adjust(*problem, iterations=10)
    monkeypatch.setattr(window, "project", reference_project)
    monkeypatch.setattr(window, "normal_equations", reference_normal_equations)
    reference = bundle_adjust(*problem, iterations=10)
    assert not np.array_equal(compiled[0], problem[0])  # it moved the poses
    for x, y in zip(compiled, reference):
        _assert_same(x, y)
