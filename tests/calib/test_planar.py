"""The planar route's compiled twin."""

import numpy as np
from calib_helpers import random_moment, random_orthonormal

from ocalib.calib.stages import planar_kernel
from ocalib.calib.stages.handeye import translation_quadratic
from ocalib.calib.stages.planar import planar_rotation


def test_planar_rotation_twin(generator):
    V, Z = random_orthonormal(generator, 5), random_moment(generator, 5)
    P, p, c = quadratic = translation_quadratic(Z)
    want_dR, want_axis = planar_rotation(quadratic, V)
    for b in range(len(V)):
        dR, axis = np.empty((3, 3)), np.empty(3)
        planar_kernel.planar_rotation((P[b].numpy(), p[b].numpy(), float(c[b])), V[b].numpy(), dR, axis,
                                      planar_kernel.workspace())  # fmt: skip
        np.testing.assert_allclose(dR, want_dR[b].numpy(), rtol=0, atol=1e-10)
        np.testing.assert_allclose(axis, want_axis[b].numpy(), rtol=0, atol=1e-12)
