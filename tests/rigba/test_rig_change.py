"""The rig estimator's per-camera extrinsic track: when a covariance determines an extrinsic."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ocalib.rigba.change import determines, with_unobservable


@pytest.mark.parametrize(
    ("rotation_deg", "translation_m", "vertical_unobservable", "expected"),
    [
        ((0.1, 0.4, 0.1), (0.05, 0.05, 0.05), False, True),
        ((0.1, 0.6, 0.1), (0.05, 0.05, 0.05), False, False),  # one rotation axis over 0.5 deg
        ((0.1, 0.1, 0.1), (0.05, 0.2, 0.05), True, True),  # a car's height: the two best directions count
        ((0.1, 0.1, 0.1), (0.05, 0.2, 0.15), False, False),  # the second-best direction over 0.1 m
    ],
)
def test_a_covariance_determines_an_extrinsic_by_its_two_best_translation_directions(
    rotation_deg, translation_m, vertical_unobservable, expected
):
    """``determines`` against the 1-sigmas read off a rotated diagonal covariance (the translation block turned by
    30 deg about the vertical: the test is on its eigen-directions, not its axes)."""
    R = Rotation.from_euler("y", 30, degrees=True).as_matrix()
    covariance = np.zeros((6, 6))
    covariance[:3, :3] = np.diag(np.radians(rotation_deg)) ** 2
    covariance[3:, 3:] = R @ np.diag(translation_m) ** 2 @ R.T
    if vertical_unobservable:
        covariance = with_unobservable(covariance, np.array([[0.0, 1.0, 0.0]]))
    assert determines(covariance, (0.5, 0.1)) is expected
