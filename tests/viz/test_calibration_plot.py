"""The calibration trace figure: the rotation error it draws, against OpenCV's rotation vectors."""

import cv2
import numpy as np
import torch

from ocalib.geometry.quaternion import rotation_matrix_to_quaternion
from ocalib.sim.trajectory import random_rig
from ocalib.viz.calibration import plot_trace, rotation_error_deg


def test_rotation_error_is_the_rotation_vector_of_truth_to_estimate():
    g = torch.Generator().manual_seed(0)
    truth = random_rig(g)[:3, :3].numpy()
    delta = cv2.Rodrigues(np.array([0.02, -0.05, 0.01]))[0]  # the error, about camera k's axes
    estimate = truth @ delta
    q = rotation_matrix_to_quaternion(torch.from_numpy(np.stack([estimate, truth]))).numpy()
    error = rotation_error_deg(q, q[1])
    np.testing.assert_allclose(error[0], np.degrees(cv2.Rodrigues(truth.T @ estimate)[0].ravel()), atol=1e-9)
    np.testing.assert_allclose(error[1], 0, atol=1e-12)


def test_plot_with_truth_writes_a_png(tmp_path):
    F, K = 30, 1
    g = torch.Generator().manual_seed(1)
    X = random_rig(g).numpy()
    q = np.tile(rotation_matrix_to_quaternion(torch.from_numpy(X[:3, :3])).numpy(), (F, K, 1))
    trace = {
        "frame": np.arange(F), "time": np.full(F, np.nan), "quaternion": q,
        "translation": np.tile(X[:3, 3], (F, K, 1)), "rotation_std_deg": np.full((F, K, 3), 0.1),
        "translation_std": np.full((F, K, 3), 0.01), "scale": np.ones((F, K, 1)), "scale_std": np.full((F, K, 1), 0.01),
        "rotation_singular_values": np.tile([1.0, 0.8, 0.5, 0.01], (F, K, 1)),
        "rotation_observable": np.ones((F, K, 1)), "planar_motion": np.zeros((F, K, 1)),
        "rotation_residual_deg": np.full((F, K, 1), 0.2), "translation_residual": np.full((F, K, 1), 0.01),
    }  # fmt: skip
    for truth in (None, X[None]):
        path = tmp_path / f"trace_{truth is None}.png"
        plot_trace(trace, ["cam1.txt"], path, truth=truth)
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
