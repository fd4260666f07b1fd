"""The joint refinement's compiled twin."""

import numpy as np
import pytest
import torch
from calib_helpers import entry, head_statistics

from ocalib.calib.stages import refine_kernel, solve_kernel
from ocalib.calib.stages.refine import REFINE_MODES, REFINE_STEPS, refine_estimate
from ocalib.calib.stages.rotation import RotationSystem
from ocalib.calib.stages.solve import closed_form


@pytest.mark.parametrize("mode", REFINE_MODES)
def test_refine_estimate_twin(generator, mode):
    """From the closed form of general and planar motion, every frame from the first."""
    rotation, quadratic, translation_rows, reverse = head_statistics(generator)
    start = closed_form(rotation, quadratic)
    want = refine_estimate(start, rotation, quadratic, translation_rows, mode, reverse=reverse)
    assert want["refined"].any() == bool(mode) and not want["refined"].all()
    x = torch.cat([start["translation"], start["scale"][:, None]], -1)
    for i in range(len(translation_rows)):
        fields = (start["quaternion"], start["rotation"], x, start["rotation_singular_values"], start["planar_axis"])
        est = solve_kernel.Estimate(*(f[i].numpy().copy() for f in fields))
        flags = (bool(start["rotation_observable"][i]), bool(start["planar_motion"][i]))
        refined = refine_kernel.refine_estimate(est, RotationSystem(*entry(rotation, i)), entry(quadratic, i),
                                                entry(reverse, i), float(translation_rows[i]),
                                                refine_kernel.REFINE_CODES[mode], REFINE_STEPS, flags,
                                                refine_kernel.workspace())  # fmt: skip
        assert refined == want["refined"][i]
        got = {"quaternion": est.quaternion, "rotation": est.rotation, "translation": est.translation_scale[:3],
               "scale": est.translation_scale[3]}  # fmt: skip
        for name, value in got.items():
            np.testing.assert_allclose(value, want[name][i], rtol=1e-8, atol=1e-8, err_msg=name)
