import numpy as np
import pycolmap
import pytest
from scipy.spatial.transform import Rotation

from ocalib.rigba.metric_prior import off_origin


@pytest.mark.parametrize("shape", ["level turn", "tilted plane", "spread"])
def test_positions_moved_off_the_origin_give_colmap_their_similarity(shape):
    """COLMAP's Sim(3) RANSAC rejects positions in a plane through the origin (a level drive re-referenced to its
    first frame); moved by ``off_origin`` (both sides alike), it recovers the similarity that maps a reconstruction's
    positions onto them, as it does for positions spread in 3-D."""
    rng = np.random.default_rng(3)
    angle = np.linspace(0.0, 0.8, 40)
    positions = np.stack([20 * np.sin(angle), 0 * angle, 20 * (1 - np.cos(angle))], 1)  # y = 0, from the origin
    if shape == "tilted plane":
        positions = positions @ Rotation.from_rotvec([0.4, 0.0, -0.3]).as_matrix().T
    if shape == "spread":
        positions = positions + rng.normal(0, 2.0, positions.shape)
    scale, turn, t = 0.4, Rotation.from_rotvec([0.2, -1.0, 0.5]).as_matrix(), np.array([3.0, -1.0, 7.0])
    reconstruction = (positions - t) @ turn / scale  # its own frame and units: turn^T (p - t) / scale
    options = pycolmap.RANSACOptions(max_error=0.05, random_seed=0)
    if shape != "spread":
        assert pycolmap.estimate_sim3d_robust(reconstruction, positions, options) is None  # plane through the origin
    shift = off_origin(positions)
    found = pycolmap.estimate_sim3d_robust(reconstruction, positions + shift, options)["tgt_from_src"]
    np.testing.assert_allclose(found.scale, scale, rtol=1e-9)
    np.testing.assert_allclose(found.rotation.matrix(), turn, atol=1e-9)
    np.testing.assert_allclose(found.translation, t + shift, atol=1e-9)
    centred = positions + shift
    assert np.linalg.matrix_rank(centred[:3].T) == 3  # any three of them leave the origin's plane
