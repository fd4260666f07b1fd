"""The change test's compact running sums and solves equal their dense references, and it runs without scipy.stats."""

import subprocess
import sys

import numpy as np
import torch

from ocalib.calib.drivers.change import _cumulative, _pinv, _split_ratio, handeye_residuals, jacobian_basis, motions
from ocalib.calib.poses.pipeline import RigPoses, calibrate_rig
from ocalib.sim.trajectory import add_noise, knocked, lds_trajectory, random_rig, rig_trajectories


def test_the_ratio_from_the_jacobians_coefficients_equals_the_one_from_the_jacobians():
    g = torch.Generator().manual_seed(5)
    poses = add_noise(rig_trajectories(lds_trajectory(400, g), random_rig(g)[None]), 0.002, g).numpy()
    A, B = motions(poses[:, 0])[1:], motions(poses[:, 1])[1:]
    R, t = np.broadcast_to(np.eye(3), (len(A), 3, 3)), np.broadcast_to(np.zeros(3), (len(A), 3))
    r, J = handeye_residuals(A, B, R, t, np.full(len(A), 1.3))
    q = np.concatenate([J[:, :3, :3].reshape(-1, 9), J[:, 3:, 6]], 1)  # I - R_A, R t_B
    np.testing.assert_array_equal(np.einsum("tk,kai->tai", q, jacobian_basis(1.3)), J)
    ends = np.arange(150, len(A) + 1)
    a, b = np.maximum(ends - 330, 0), ends - 30
    dense = _split_ratio(_cumulative(r, J), a, b, ends)
    compact = _split_ratio(_cumulative(r, q, jacobian_basis(1.3)), a, b, ends)
    for x, y in zip(dense, compact):
        np.testing.assert_allclose(x, y, rtol=1e-7, atol=1e-9)


def test_the_pseudo_inverse_by_cholesky_equals_numpys_and_cuts_where_numpys_does():
    rng = np.random.default_rng(1)
    X = rng.normal(size=(40, 7, 9))
    H = X @ X.mT
    H[:10] = X[:10, :, :5] @ X[:10, :, :5].mT  # rank 5
    H[10:20] = np.diag([1.0, 1, 1, 1, 1, 1, 1e-9])  # condition 1e9: its smallest eigenvalue is cut at 1e-8
    inverse, full = _pinv(H, 1e-8)
    np.testing.assert_allclose(inverse, np.linalg.pinv(H, rcond=1e-8, hermitian=True), rtol=1e-7, atol=1e-9)
    assert not full[:20].any() and full[20:].all()


def test_calibrate_rig_without_the_change_test_keeps_the_knock_and_its_trace_columns():
    g = torch.Generator().manual_seed(0)
    X = knocked(random_rig(g), 600, 300)
    poses = add_noise(rig_trajectories(lds_trajectory(600, g), X[:, None]), 0.002, g).numpy()
    rig = RigPoses(["a.txt", "b.txt"], poses, None, np.zeros((600, 2), int), [None, None], [None, None])
    tested, untested = calibrate_rig(rig), calibrate_rig(rig, change_test=None)
    assert len(tested.changes) == 1 and untested.changes == []
    assert set(untested.trace) == set(tested.trace) and np.isnan(untested.trace["change_frame"]).all()
    np.testing.assert_array_equal(untested.trace["scale"][:300], tested.trace["scale"][:300])


def test_the_change_test_imports_no_scipy_stats():
    code = "import sys, ocalib.calib.poses.pipeline; print('scipy.stats' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout == "False\n"
