"""Compiled twin (numba) of :func:`ocalib.calib.stages.planar.planar_rotation`, for one entry (no batch dimension;
results written into the arrays passed).

Convention: as :mod:`ocalib.calib.stages.planar`: the axis ``n`` in camera 0's frame; quaternions (w, x, y, z).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ocalib.calib.stages import translation_kernel
from ocalib.calib.stages.handeye_kernel import normal_equations
from ocalib.calib.stages.linalg_kernel import jit, quaternion_to_rotation_matrix
from ocalib.calib.stages.translation_kernel import pinv_solve


class Workspace(NamedTuple):
    """Scratch arrays of :func:`planar_rotation`."""

    solve: translation_kernel.Workspace
    R4: np.ndarray  # (3, 3)
    c: np.ndarray  # (6,) the unknowns (dT, s, s cos(theta), s sin(theta))


@jit
def workspace():
    return Workspace(translation_kernel.workspace(), np.empty((3, 3)), np.empty(6))


@jit
def planar_rotation(quadratic, V, dR, axis, work):
    """:func:`~ocalib.calib.stages.planar.planar_rotation`: the rotation ``dR`` (3, 3) and the axis ``n`` (3,), written,
    from the moment's ``quadratic`` ``(P, p, c)`` and the rotation system's right singular vectors ``V`` (4, 4).
    ``work``: :func:`workspace`."""
    v3w, v3x, v3y, v3z = V[0, 2], -V[1, 2], -V[2, 2], -V[3, 2]  # conj(v3); n = v4 * conj(v3)
    v4w, v4x, v4y, v4z = V[0, 3], V[1, 3], V[2, 3], V[3, 3]
    axis[0] = v4w * v3x + v4x * v3w + v4y * v3z - v4z * v3y
    axis[1] = v4w * v3y - v4x * v3z + v4y * v3w + v4z * v3x
    axis[2] = v4w * v3z + v4x * v3y - v4y * v3x + v4z * v3w
    norm = max(math.sqrt(axis[0] ** 2 + axis[1] ** 2 + axis[2] ** 2), 1e-300)
    for i in range(3):
        axis[i] /= norm
    R4, maps = work.R4, work.solve.maps
    quaternion_to_rotation_matrix(V[:, 3], R4)
    for i in range(3):  # the maps n n^T R4, (I - n n^T) R4, [n]x R4
        for m in range(3):
            along, across = 0.0, 0.0
            for l in range(3):
                nil = axis[i] * axis[l]
                along += nil * R4[l, m]
                across += ((1.0 if i == l else 0.0) - nil) * R4[l, m]
            if i == 0:
                cross = -axis[2] * R4[1, m] + axis[1] * R4[2, m]
            elif i == 1:
                cross = axis[2] * R4[0, m] - axis[0] * R4[2, m]
            else:
                cross = -axis[1] * R4[0, m] + axis[0] * R4[1, m]
            maps[0, i, m], maps[1, i, m], maps[2, i, m] = along, across, cross
    normal_equations(quadratic, maps, 3, work.solve.H, work.solve.g)
    c = work.c
    pinv_solve(work.solve.H, work.solve.g, 6, c, work.solve)
    theta = math.atan2(c[5], c[4])
    ct, st = math.cos(theta), math.sin(theta)
    for i in range(3):
        for m in range(3):
            dR[i, m] = maps[0, i, m] + ct * maps[1, i, m] + st * maps[2, i, m]
