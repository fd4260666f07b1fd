"""Compiled twin (numba) of :func:`ocalib.calib.stages.solve.closed_form`, for one rig and camera k (no batch dimension;
results written into the arrays passed).

Convention: as :mod:`ocalib.calib.stages.solve`: ``T_cam0_camk`` (``p_cam0 = dR p_camk + dT``), ``s`` multiplies
camera-k units into camera-0 units, quaternions (w, x, y, z) with w >= 0.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ocalib.calib.stages import planar_kernel
from ocalib.calib.stages.linalg_kernel import jit, quaternion_to_rotation_matrix, rotation_matrix_to_quaternion
from ocalib.calib.stages.planar_kernel import planar_rotation
from ocalib.calib.stages.rotation import PLANAR_SIGNIFICANCE, ROTATION_OBSERVABLE_SIGNIFICANCE
from ocalib.calib.stages.rotation_kernel import excited, rotation_solution, singular_values
from ocalib.calib.stages.translation_kernel import solve_translation


class Estimate(NamedTuple):
    """One rig's and camera's estimate: the arrays of the :class:`~ocalib.calib.drivers.result.Calibration` fields (its
    flags are the twins' return values)."""

    quaternion: np.ndarray  # (4,)
    rotation: np.ndarray  # (3, 3)
    translation_scale: np.ndarray  # (4,) translation and scale
    rotation_singular_values: np.ndarray  # (4,)
    planar_axis: np.ndarray  # (3,)


Workspace = planar_kernel.Workspace  # closed_form's scratch: the planar route's, which holds the translation solve's
workspace = planar_kernel.workspace


@jit
def closed_form(rotation, quadratic, est, work):
    """:func:`~ocalib.calib.stages.solve.closed_form` of one rig and camera k: ``rotation`` a
    :class:`~ocalib.calib.stages.rotation.RotationSystem` (``S2`` (4,), ``V`` (4, 4), ``rotation_rows``), ``quadratic``
    ``(P, p, c)`` of the translation moment; writes ``est`` (:class:`Estimate`), returns ``(observable, planar)``.
    ``work``: :func:`workspace`."""
    S2, V, rows = rotation
    S, q, dR, x, axis = (
        est.rotation_singular_values,
        est.quaternion,
        est.rotation,
        est.translation_scale,
        est.planar_axis,
    )
    S[0], S[1], S[2], S[3] = singular_values(S2)
    q[0], q[1], q[2], q[3] = rotation_solution(V)
    quaternion_to_rotation_matrix(q, dR)
    planar = excited(S, rows, 1, ROTATION_OBSERVABLE_SIGNIFICANCE) and not excited(S, rows, 2, PLANAR_SIGNIFICANCE)
    axis[:] = 0.0
    if planar:
        planar_rotation(quadratic, V, dR, axis, work)
        rotation_matrix_to_quaternion(dR, q)
    solve_translation(quadratic, dR, x, work.solve)
    # Planar motion: the translation along the rotation axis is unobservable; report the minimum-norm value, 0.
    along = axis[0] * x[0] + axis[1] * x[1] + axis[2] * x[2]
    for i in range(3):
        x[i] -= axis[i] * along
    return excited(S, rows, 2, ROTATION_OBSERVABLE_SIGNIFICANCE), planar
