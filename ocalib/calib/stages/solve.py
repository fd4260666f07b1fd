"""The closed-form estimate from the kept statistics, shared by the streaming head (:mod:`ocalib.calib.drivers.online`)
and the whole-sequence path (:mod:`ocalib.calib.drivers.sequence`).

From the rotation system (``S2, V``: squared singular values and right singular vectors) and the translation
moment's quadratic form: the closed-form rotation (the null vector; on planar motion the translation route of
:mod:`ocalib.calib.stages.planar`), then the exact least-squares translation and scale with that rotation. The joint
refinement of :mod:`ocalib.calib.stages.refine` starts from it. The compiled twin is in
:mod:`ocalib.calib.stages.solve_kernel`.

Convention: ``T_cam0_camk`` (``p_cam0 = dR p_camk + dT``), ``s`` multiplies camera-k units into camera-0
units, quaternions (w, x, y, z) with w >= 0. Any leading batch shape (rigs, cameras, frames).
"""

from __future__ import annotations

import torch
from torch import Tensor

from ocalib.calib.stages.planar import planar_rotation
from ocalib.calib.stages.rotation import (
    RotationSystem,
    planar_motion,
    rotation_observable,
    rotation_solution,
    singular_values,
)
from ocalib.calib.stages.translation import minimum_norm, solve_translation
from ocalib.geometry.quaternion import quaternion_to_rotation_matrix, rotation_matrix_to_quaternion


def closed_form(rotation: RotationSystem, quadratic: tuple[Tensor, Tensor, Tensor]) -> dict[str, Tensor]:
    """Extrinsics from the statistics, in closed form.

    Args:
        rotation: the weighted rotation rows (...). quadratic: ``(P, p, c)`` of the weighted translation moment
            (:func:`~ocalib.calib.stages.handeye.translation_quadratic`).

    Returns the :class:`~ocalib.calib.drivers.result.Calibration` fields of the estimate: ``quaternion`` (..., 4),
    ``rotation`` (..., 3, 3), ``translation`` (..., 3), ``scale`` (...), ``rotation_singular_values`` (..., 4),
    ``rotation_observable``, ``planar_motion`` (...) bool, ``planar_axis`` (..., 3) (zero unless planar: the
    translation along it is unobservable and reported as 0, the minimum-norm value) and ``refined`` (...) False.
    Kernel twin: :func:`ocalib.calib.stages.solve_kernel.closed_form`.
    """
    S = singular_values(rotation.S2)
    quat = rotation_solution(rotation.V)
    dR = quaternion_to_rotation_matrix(quat)
    planar = planar_motion(S, rotation.rotation_rows)
    axis = torch.zeros_like(quat[..., 1:])
    # On the CPU the planar solve runs on the planar entries only (none: skipped); elsewhere (and in a compiled
    # graph) on all of them, so that a frame never waits for the host.
    if planar.device.type != "cpu" or torch.compiler.is_compiling():
        dR_planar, axis = planar_rotation(quadratic, rotation.V)
        axis = torch.where(planar[..., None], axis, 0.0)
        dR = torch.where(planar[..., None, None], dR_planar, dR)
        quat = torch.where(planar[..., None], rotation_matrix_to_quaternion(dR), quat)
    elif bool(planar.any()):
        dR_planar, axis_planar = planar_rotation(tuple(x[planar] for x in quadratic), rotation.V[planar])
        dR, axis = dR.index_put((planar,), dR_planar), axis.index_put((planar,), axis_planar)
        quat = quat.index_put((planar,), rotation_matrix_to_quaternion(dR_planar))
    x = solve_translation(quadratic, dR)
    dT = minimum_norm(x[..., :3], axis)  # the solver's rank cut-off keeps whatever the noise made of the axis's part
    return {
        "quaternion": quat,
        "rotation": dR,
        "translation": dT,
        "scale": x[..., 3],
        "rotation_singular_values": S,
        "rotation_observable": rotation_observable(S, rotation.rotation_rows),
        "planar_motion": planar,
        "planar_axis": axis,
        "refined": torch.zeros_like(planar),
    }
