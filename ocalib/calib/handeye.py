"""The hand-eye equations of a rigid rig, for one motion pair (camera 0 moves by ``(R0, t0)`` while
camera k moves by ``(R1, t1)`` over the same time interval).

Convention: the unknown ``X = (dR, dT, s)`` is the pose of camera k in camera 0's frame
(``p_cam0 = dR p_camk + dT``) and ``s`` multiplies camera-k units into camera-0 units. A motion
``(R, t)`` is a camera's pose at the end of the interval in its own frame at the start
(``T_start^-1 T_end``). Then

* rotation:     ``R0 dR = dR R1``, in quaternions ``q0 * dq = dq * q1``, i.e. ``A dq = 0`` with
  ``A = L(q0) - R(q1)`` (4x4);
* translation:  ``(I - R0) dT + s dR t1 = t0``, linear in ``x = (dT, s)``.

The translation rows depend on ``dR``. To re-solve them with the latest ``dR`` at every frame in O(1)
they are kept as the second moment of a 15-vector ``z = (vec(I - R0), t1, t0)`` (see
:func:`translation_features`), from which :func:`normal_equations` assembles the normal equations
for any rotation model.
"""

from __future__ import annotations

from functools import lru_cache

import torch
from torch import Tensor

from ocalib.geometry.quaternion import canonical_quaternion, left_product_matrix, right_product_matrix

FEATURES = 15  # len(z): 9 entries of I - R0 (row-major), t1 (3), t0 (3)


def rotation_block(q0: Tensor, q1: Tensor) -> Tensor:
    """``A = L(q0) - R(q1)`` (..., 4, 4) from motion quaternions (..., 4), (w, x, y, z).

    Both quaternions are put on the ``w >= 0`` hemisphere first: the rotation angles of corresponding
    motions are equal, so their ``w`` agree, and with opposite signs the block would describe a
    rotation 180 degrees away.
    """
    return left_product_matrix(canonical_quaternion(q0)) - right_product_matrix(canonical_quaternion(q1))


def translation_features(R0: Tensor, t0: Tensor, t1: Tensor) -> Tensor:
    """``z = (vec(I - R0), t1, t0)`` (..., 15) from R0 (..., 3, 3), t0 (..., 3), t1 (..., 3)."""
    eye = torch.eye(3, dtype=R0.dtype, device=R0.device)
    return torch.cat([(eye - R0).flatten(-2), t1, t0], -1)


def translation_rows(R0: Tensor, t0: Tensor, t1: Tensor, dR: Tensor) -> tuple[Tensor, Tensor]:
    """The explicit rows ``B = [I - R0, dR t1]`` (..., 3, 4) and ``b = t0`` (..., 3)."""
    eye = torch.eye(3, dtype=R0.dtype, device=R0.device)
    return torch.cat([eye - R0, (dR @ t1.unsqueeze(-1))], -1), t0


def normal_equations(Z: Tensor, maps: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Normal equations of ``(I - R0) dT + sum_k c_k L_k t1 = t0`` from the moment ``Z = sum w z z^T``.

    Args:
        Z: (..., 15, 15) second moment of :func:`translation_features`.
        maps: (..., m, 3, 3) the linear maps ``L_k`` applied to ``t1``. The general model has one map, ``dR`` (unknowns
            ``dT, s``); the planar model has three (see :mod:`ocalib.calib.planar`).

    Returns:
        H (..., 3+m, 3+m), g (..., 3+m), and ``sum w |t0|^2`` (...), so that the weighted residual is
        ``|t0|^2 - 2 x.g + x^T H x`` for the unknown ``x = (dT, c)``.
    """
    m = maps.shape[-3]
    # z' = D z = (vec(I - R0), L_1 t1, ..., L_m t1, t0), and the moment of z' is D Z D^T.
    D = Z.new_zeros(*maps.shape[:-3], 12 + 3 * m, FEATURES)
    D[..., :9, :9] = torch.eye(9, dtype=Z.dtype, device=Z.device)
    D[..., 9 : 9 + 3 * m, 9:12] = maps.flatten(-3, -2)
    D[..., 9 + 3 * m :, 12:] = torch.eye(3, dtype=Z.dtype, device=Z.device)
    Zd = D @ Z @ D.mT
    # Equation r of a pair reads z'[idx[r]] = (row r of I - R0, (L_k t1)_r for each k | (t0)_r).
    idx = _row_index(m, Z.device)
    K = Zd[..., idx[:, :, None], idx[:, None, :]].sum(-3)
    n = 3 + m
    return K[..., :n, :n], K[..., :n, n], K[..., n, n]


@lru_cache(maxsize=None)
def _row_index(m: int, device: torch.device) -> Tensor:
    """(3, 4 + m) indices into z' of equation r's unknown coefficients and target (made outside
    inference mode, like every cached constant, so that autograd can use it later)."""
    with torch.inference_mode(False):
        return torch.tensor(
            [[3 * r, 3 * r + 1, 3 * r + 2] + [9 + 3 * k + r for k in range(m)] + [9 + 3 * m + r] for r in range(3)],
            device=device,
        )
