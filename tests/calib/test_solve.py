"""The closed form's compiled twin."""

import numpy as np
from calib_helpers import entry, head_statistics

from ocalib.calib.stages import solve_kernel
from ocalib.calib.stages.rotation import RotationSystem
from ocalib.calib.stages.solve import closed_form


def test_closed_form_twin(generator):
    """General and planar motion, from the first frames (rotation not observable) on."""
    rotation, quadratic, translation_rows, _ = head_statistics(generator)
    want = closed_form(rotation, quadratic)
    assert want["rotation_observable"].any() and want["planar_motion"].any() and not want["rotation_observable"].all()
    for i in range(len(translation_rows)):
        est = solve_kernel.Estimate(np.empty(4), np.empty((3, 3)), np.empty(4), np.empty(4), np.empty(3))
        observable, planar = solve_kernel.closed_form(RotationSystem(*entry(rotation, i)), entry(quadratic, i), est,
                                                      solve_kernel.workspace())  # fmt: skip
        assert (observable, planar) == (want["rotation_observable"][i], want["planar_motion"][i])
        np.testing.assert_allclose(est.rotation_singular_values, want["rotation_singular_values"][i], rtol=1e-14)
        # With fewer than 3 motion pairs the planar route's 6 unknowns are underdetermined: rounding picks a solution.
        if planar and translation_rows[i] < 3:
            continue
        got = {"quaternion": est.quaternion, "rotation": est.rotation, "translation": est.translation_scale[:3],
               "scale": est.translation_scale[3], "planar_axis": est.planar_axis}  # fmt: skip
        for name, value in got.items():
            np.testing.assert_allclose(value, want[name][i], rtol=1e-8, atol=1e-8, err_msg=name)
