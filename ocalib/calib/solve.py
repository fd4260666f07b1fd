"""The estimate from the kept statistics, shared by the streaming head (:mod:`ocalib.calib.online`) and the
whole-sequence path (:mod:`ocalib.calib.sequence`).

From the rotation system (``S2, V``: squared singular values and right singular vectors) and the translation
moment ``Z``: the closed-form rotation (the null vector; on planar motion the translation route of
:mod:`ocalib.calib.planar`), the exact least-squares translation and scale with that rotation, then the
joint refinement of :mod:`ocalib.calib.refine` where two rotation directions are excited and the motion is not
planar (``refine=True``), or only where the rotation rows alone leave the rotation unobservable
(``refine="unobservable"``: for monocular front ends, see :data:`REFINE_MODES`).

Convention: ``T_cam0_camk`` (``p_cam0 = dR p_camk + dT``), ``s`` multiplies camera-k units into camera-0
units, quaternions (w, x, y, z) with w >= 0. Any leading batch shape (rigs, cameras, frames).
"""

from __future__ import annotations

import torch
from torch import Tensor

from ocalib.calib.handeye import translation_quadratic
from ocalib.calib.planar import planar_rotation
from ocalib.calib.refine import joint_refine
from ocalib.calib.rotation import excited, planar_motion, rotation_observable, rotation_solution, singular_values
from ocalib.calib.translation import solve_translation
from ocalib.geometry.quaternion import quaternion_to_rotation_matrix, rotation_matrix_to_quaternion

# The joint refinement lets the translation rows move the rotation. Where those rows are trustworthy (poses from
# SLAM, metric VO) that makes it more accurate (docs/simulation.md: 0.137 vs 0.191 deg on OpenCV's protocol). A
# monocular front end (OpenCV VO, a pose network) gets translation directions wrong in a biased way (the
# rotation-translation ambiguity): the refinement weighs rows by their scatter, which does not see a bias, and
# pulls the rotation off (measured on the held-out handheld rig: OpenCV VO 1.6 deg closed form vs 5.7 refined; the
# networks 5.5 vs 6.9, 5.7 vs 13.5). "unobservable" refines only where the rotation needs the translation rows:
# near-planar motion whose third rotation direction the rotation rows do not fix.
REFINE_MODES = (True, False, "unobservable")


def estimate(
    S2: Tensor,
    V: Tensor,
    Z: Tensor,
    rotation_rows: Tensor,
    translation_rows: Tensor,
    refine: bool | str = True,
    refine_steps: int = 3,
) -> dict[str, Tensor]:
    """Extrinsics from the statistics.

    Args:
        S2: (..., 4) squared singular values (descending), V: (..., 4, 4) right singular vectors of the
            weighted rotation rows. Z: (..., 15, 15) weighted translation moment.
        rotation_rows, translation_rows: (...) weighted numbers of motion pairs behind them.
        refine: one of :data:`REFINE_MODES`: True runs the joint refinement, False keeps the closed form,
            ``"unobservable"`` refines only where the rotation is not observable from the rotation rows.
            refine_steps: the refinement's steps.

    Returns:
        ``quaternion`` (..., 4), ``rotation`` (..., 3, 3), ``translation`` (..., 3), ``scale`` (...),
        ``singular_values`` (..., 4), ``observable``, ``planar`` (...) bool, ``axis`` (..., 3) (zero unless
        planar), ``refined`` (...) bool, and the moment's ``quadratic`` (P, p, c).
    """
    S = singular_values(S2)
    quat = rotation_solution(V)
    dR = quaternion_to_rotation_matrix(quat)
    planar, observable = planar_motion(S, rotation_rows), rotation_observable(S, rotation_rows)
    quadratic = translation_quadratic(Z)
    axis = torch.zeros_like(quat[..., 1:])
    # On the CPU the planar solve runs on the planar entries only (none: skipped); elsewhere (and in a compiled
    # graph) on all of them, so that a frame never waits for the host.
    if planar.device.type != "cpu" or torch.compiler.is_compiling():
        dR_planar, axis = planar_rotation(quadratic, V)
        axis = torch.where(planar[..., None], axis, 0.0)
        dR = torch.where(planar[..., None, None], dR_planar, dR)
        quat = torch.where(planar[..., None], rotation_matrix_to_quaternion(dR), quat)
    elif bool(planar.any()):
        dR_planar, axis_planar = planar_rotation(tuple(x[planar] for x in quadratic), V[planar])
        dR, axis = dR.index_put((planar,), dR_planar), axis.index_put((planar,), axis_planar)
        quat = quat.index_put((planar,), rotation_matrix_to_quaternion(dR_planar))

    x = solve_translation(quadratic, dR)
    refined = torch.zeros_like(planar)
    if refine and refine_steps > 0:
        M = (V * S2.unsqueeze(-2)) @ V.mT
        # Where at least two rotation directions are excited and the motion is not planar (rotation observable,
        # or weak in the third direction: the translation rows then carry it).
        active = excited(S, rotation_rows, 1) & ~planar & (translation_rows >= 3)
        if refine == "unobservable":
            active = active & ~observable
        quat, x, refined = joint_refine(M, quadratic, quat, x, rotation_rows, translation_rows, active, refine_steps)
        dR = torch.where(refined[..., None, None], quaternion_to_rotation_matrix(quat), dR)

    # Planar motion: the translation along the rotation axis (a car's height) is unobservable. The solver's
    # rank cut-off keeps whatever the noise made of it; report the minimum-norm value, 0.
    dT = x[..., :3]
    dT = dT - axis * (axis * dT).sum(-1, keepdim=True)
    return {
        "quaternion": quat,
        "rotation": dR,
        "translation": dT,
        "scale": x[..., 3],
        "singular_values": S,
        "observable": observable,
        "planar": planar,
        "axis": axis,
        "refined": refined,
        "quadratic": quadratic,
    }
