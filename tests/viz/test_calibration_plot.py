"""The calibration trace figure: the rotation error it draws, against OpenCV's rotation vectors."""

import cv2
import numpy as np
import pytest
import torch

from ocalib.geometry.angles import rotation_error_deg
from ocalib.geometry.quaternion import rotation_matrix_to_quaternion
from ocalib.sim.trajectory import random_rig
from ocalib.viz.calibration import plot_trace


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


def _figure_texts(monkeypatch, trace, truth) -> list[str]:
    """Every title, legend label and text of the figure plot_trace draws."""
    import ocalib.viz.calibration as module

    figures = []
    monkeypatch.setattr(module, "save_figure", lambda fig, path, dpi=90: figures.append(fig))
    plot_trace(trace, ["cam1.txt"], "unused.png", truth=truth)
    texts = []
    for ax in figures[0].axes:
        texts += [ax.get_title(), *ax.get_legend_handles_labels()[1], *(t.get_text() for t in ax.texts)]
    return texts


def _trace(F: int, q: np.ndarray, observable: bool) -> dict:
    K = 1
    return {
        "frame": np.arange(F), "time": np.full(F, np.nan), "quaternion": np.tile(q, (F, K, 1)),
        "translation": np.tile([0.5, 0.0, -0.2], (F, K, 1)),
        "rotation_std_deg": np.full((F, K, 3), 0.1 if observable else 0.0),
        "translation_std": np.full((F, K, 3), 0.01), "scale": np.ones((F, K, 1)), "scale_std": np.full((F, K, 1), 0.01),
        "rotation_singular_values": np.tile([1.0, 0.8, 0.5 if observable else 0.0, 0.0], (F, K, 1)),
        "rotation_observable": np.full((F, K, 1), float(observable)), "planar_motion": np.zeros((F, K, 1)),
        "rotation_residual_deg": np.zeros((F, K, 1)), "translation_residual": np.zeros((F, K, 1)),
    }  # fmt: skip


def test_plot_shows_the_truth_beside_the_estimate(monkeypatch):
    """The true rotation's angle, axis and roll/pitch/yaw in the title, beside the estimate's (a rotation of 120 deg
    about y, whose roll and yaw are 180: printed +180, never -180), and the true translation direction."""
    X = np.eye(4)
    X[:3, :3] = cv2.Rodrigues(np.array([0.0, np.radians(120), 0.0]))[0]
    X[:3, 3] = [0.6, 0.0, -0.8]
    q = rotation_matrix_to_quaternion(torch.from_numpy(X[:3, :3])).numpy()
    texts = "\n".join(_figure_texts(monkeypatch, _trace(20, q, True), X[None]))
    assert "truth: 120.00 deg about (+0.000, +1.000, +0.000); roll, pitch, yaw +180.0, +60.0, +180.0 deg" in texts
    assert "about x, std 0.1" in texts
    assert f"tx = 0.5000, truth {0.6 * np.hypot(0.5, 0.2):+.4f}" in texts  # the true direction at the final length
    texts = "\n".join(_figure_texts(monkeypatch, _trace(20, q, True), None))
    assert "truth" not in texts


def test_plot_shows_an_unobservable_rotation_as_such(monkeypatch):
    texts = _figure_texts(monkeypatch, _trace(20, np.array([1.0, 0, 0, 0]), False), None)
    assert any(t.startswith("ROTATION UNOBSERVABLE") for t in texts)
    assert not any("std" in t for t in texts if t.startswith("about"))


def _figure(monkeypatch, trace, **kwargs):
    """The matplotlib figure plot_trace draws for one camera."""
    import ocalib.viz.calibration as module

    figures = []
    monkeypatch.setattr(module, "save_figure", lambda fig, path, dpi=90: figures.append(fig))
    plot_trace(trace, ["cam1.txt"], "unused.png", **kwargs)
    return figures[0]


def test_panels_fit_the_settled_estimate_not_an_early_transient(monkeypatch):
    """A translation that starts at +-200 and settles at (0.5, 0, -0.2) from frame 40 of 100: the panel's axis
    spans the settled values with a margin (not the +-200), and says that earlier values run off it."""
    trace = _trace(100, np.array([1.0, 0, 0, 0]), True)
    trace["translation"][:40, 0] = 200 * np.sin(np.arange(40))[:, None]
    panel = _figure(monkeypatch, trace).axes[1]  # rows: rotation, translation, ...
    low, high = panel.get_ylim()
    span = 0.51 - -0.21  # the settled values -0.2..0.5 with their 1-sigma 0.01
    assert (low, high) == pytest.approx((-0.21 - 0.15 * span, 0.51 + 0.15 * span))  # and a 15 % margin
    assert any("earlier values run off it" in t.get_text() for t in panel.texts)
    steady = _figure(monkeypatch, _trace(100, np.array([1.0, 0, 0, 0]), True)).axes[1]
    assert steady.get_ylim() == pytest.approx((low, high)) and not steady.texts  # nothing ran off: no note


def test_the_bundle_adjustments_unobservable_component_is_marked(monkeypatch):
    """The bundle row labels the axes an unobservable direction has a share in as unobservable (a car's vertical
    y here, not x or z) and names the direction; without unobservable directions nothing is marked."""
    from ocalib.viz.calibration import bundle_unobservable

    trace = _trace(50, np.array([1.0, 0, 0, 0]), True)
    trace["bundle_quaternion"] = np.full((50, 1, 4), np.nan)
    trace["bundle_translation"] = np.full((50, 1, 3), np.nan)
    trace["bundle_quaternion"][-1, 0], trace["bundle_translation"][-1, 0] = [1.0, 0, 0, 0], [0.5, 0.03, -0.2]
    doc = {
        "extrinsics": [
            {"source": "bundle_adjustment", "observability": {"unobservable_translation_directions": [[0, 1, 0]]}}
        ]
    }
    assert bundle_unobservable(doc) == [[[0, 1, 0]]]
    assert bundle_unobservable({"extrinsics": [dict(doc["extrinsics"][0], source="online")]}) == [[]]
    row = _figure(monkeypatch, trace, units="metres", unobservable=bundle_unobservable(doc)).axes[-1]
    labels = row.get_legend_handles_labels()[1]
    assert labels == ["tx = +0.5000", "ty = +0.0300 (unobservable)", "tz = -0.2000"]
    assert any(t.get_text().startswith("unobservable along [+0.00, +1.00, +0.00]") for t in row.texts)
    row = _figure(monkeypatch, trace, units="metres").axes[-1]
    assert not any("unobservable" in label for label in row.get_legend_handles_labels()[1]) and not row.texts
