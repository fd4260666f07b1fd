"""A trajectory off as a real one is: the rotation's random walk and the positions' white noise have the stated
spread (their sample statistics against the closed forms)."""

import numpy as np
from scipy.spatial.transform import Rotation

from ocalib.sim.trajectory import off_trajectory


def test_a_trajectory_off_as_a_real_one_walks_in_rotation_and_scatters_in_position():
    rng = np.random.default_rng(5)
    poses = np.tile(np.eye(4), (4000, 1, 1))
    poses[:, :3, :3] = Rotation.random(4000, random_state=rng).as_matrix()
    poses[:, :3, 3] = rng.normal(0, 10, (4000, 3))
    off = off_trajectory(poses, 0.02, seed=1)
    error = Rotation.from_matrix(off[:, :3, :3] @ poses[:, :3, :3].transpose(0, 2, 1)).as_rotvec()  # world side
    steps = np.degrees(np.diff(error, axis=0))  # per frame, per axis: N(0, 0.02 deg)
    np.testing.assert_allclose(steps.std(axis=0), 0.02, rtol=0.05)
    assert np.degrees(np.linalg.norm(error[-100:], axis=1)).mean() > 0.5  # a walk (white: about 0.03 deg)
    np.testing.assert_allclose((off[:, :3, 3] - poses[:, :3, 3]).std(axis=0), 0.01, rtol=0.05)
    np.testing.assert_array_equal(off, off_trajectory(poses, 0.02, seed=1))  # seeded
