"""Pose helpers against numpy's own operations."""

import numpy as np

from ocalib.geometry.pose import cross_matrix


def test_cross_matrix_is_the_cross_product():
    a, b = np.random.default_rng(0).normal(size=(2, 5, 3))
    np.testing.assert_allclose(cross_matrix(a) @ b[..., None], np.cross(a, b)[..., None], atol=1e-12)
