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
they are kept as sums of products of the 15 features ``z = (vec(I - R0), t1, t0)`` of each row (see
:func:`translation_features`): the residual is linear in ``y = (dT, vec(s dR))``, so it is a quadratic in
``y`` for any ``(dR, dT, s)`` (:func:`translation_quadratic`), and only the 58 sums that quadratic reads are
kept (:func:`row_statistics`; the full second moment of ``z`` has 225). :func:`normal_equations` assembles
the normal equations for any rotation model from the quadratic.

Each motion pair can give its translation rows in both directions (:func:`pair_features`): the pair
from frame a to b and its reverse, whose residual lives in frame b. Their rotation rows are the same
(``|A' q| = |A q|``), their translation rows are not: the forward rows carry the rotation noise of
frame a's pose times the motion's length, the reverse rows frame b's.

The compiled twins are in :mod:`ocalib.calib.stages.handeye_kernel`.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from ocalib.geometry.quaternion import canonical_quaternion, left_product_matrix, right_product_matrix

STATISTICS = 58  # the sums of products of z the quadratic reads (row_statistics)


class TranslationMoment(NamedTuple):
    """The weighted translation rows, kept as the sums of products of their features that their quadratic reads
    (:func:`row_statistics`; the field names are the head's buffers')."""

    Z: Tensor  # (..., 58)
    translation_rows: Tensor  # (...) weighted number of motion pairs
    Z_reverse: Tensor  # (..., 58) the reverse rows' share of Z (zero with rows in one direction)


def rotation_block(q0: Tensor, q1: Tensor) -> Tensor:
    """``A = L(q0) - R(q1)`` (..., 4, 4) from motion quaternions (..., 4), (w, x, y, z).

    Both quaternions are put on the ``w >= 0`` hemisphere first: the rotation angles of corresponding
    motions are equal, so their ``w`` agree, and with opposite signs the block would describe a
    rotation 180 degrees away.
    """
    return left_product_matrix(canonical_quaternion(q0)) - right_product_matrix(canonical_quaternion(q1))


def rotation_blocks(quaternion: Tensor) -> Tensor:
    """:func:`rotation_block` (..., K, P, 4, 4) of camera 0's motions against camera k's, from every camera's motion
    quaternions (..., C, P, 4). Kernel twin: :func:`ocalib.calib.stages.handeye_kernel.rotation_blocks`."""
    return rotation_block(quaternion[..., :1, :, :].expand_as(quaternion[..., 1:, :, :]), quaternion[..., 1:, :, :])


def translation_moment(motion: Tensor, ok: Tensor, symmetric: bool) -> tuple[Tensor, Tensor]:
    """The statistics (..., K, P, 58) of the translation rows (:func:`pair_features`, :func:`row_statistics`) of
    camera 0's motions against camera k's, from every camera's motions (..., C, P, 4, 4), for the pairs ``ok``
    (..., K, P), and their reverse rows' share (zero unless ``symmetric``)."""
    z = pair_features(motion[..., :1, :, :, :].expand_as(motion[..., 1:, :, :, :]), motion[..., 1:, :, :, :], symmetric)
    stats = row_statistics(z) * ok[..., None, None]
    return stats.sum(-2), stats[..., -1, :] * symmetric


def row_statistics(z: Tensor) -> Tensor:
    """The statistics (..., 58) of translation rows with features ``z`` (..., 15), one set per row (sum them over
    rows): with ``E = I - R0``, ``sum_r E_r E_r^T`` (9), ``E[r, i] t1[j]`` at ``(i, 3 r + j)`` (27), ``t1 t1^T``
    (9), ``E^T t0`` (3), ``t0[r] t1[j]`` at ``3 r + j`` (9) and ``|t0|^2`` (1): the blocks of the quadratic
    (:func:`translation_quadratic`). Kernel twin: :func:`ocalib.calib.stages.handeye_kernel.add_row_statistics`."""
    E, t1, t0 = z[..., :9].unflatten(-1, (3, 3)), z[..., 9:12], z[..., 12:15]
    cross = E.mT.unsqueeze(-1) * t1[..., None, None, :]  # E[r, i] t1[j] at (i, r, j)
    parts = [(E.mT @ E).flatten(-2), cross.flatten(-3), (t1.unsqueeze(-1) * t1.unsqueeze(-2)).flatten(-2),
             (E.mT @ t0.unsqueeze(-1)).squeeze(-1), (t0.unsqueeze(-1) * t1.unsqueeze(-2)).flatten(-2),
             t0.square().sum(-1, keepdim=True)]  # fmt: skip
    return torch.cat(parts, -1)


def update_translation_moment(
    moment: TranslationMoment, motion: Tensor, ok: Tensor, forgetting: float, symmetric: bool
) -> TranslationMoment:
    """Add the translation rows of the pairs ``ok`` (..., K, P) of every camera's motions (..., C, P, 4, 4) to
    ``moment`` (..., K, P), old rows weighing ``forgetting``. Kernel twin:
    :func:`ocalib.calib.stages.handeye_kernel.update_translation_moment`."""
    Z, Z_reverse = translation_moment(motion, ok, symmetric)
    if forgetting != 1:
        Z, Z_reverse = forgetting * moment.Z + Z, forgetting * moment.Z_reverse + Z_reverse
    else:
        Z, Z_reverse = moment.Z + Z, moment.Z_reverse + Z_reverse
    return TranslationMoment(Z, forgetting * moment.translation_rows + ok, Z_reverse)


def translation_features(R0: Tensor, t0: Tensor, t1: Tensor) -> Tensor:
    """``z = (vec(I - R0), t1, t0)`` (..., 15) from R0 (..., 3, 3), t0 (..., 3), t1 (..., 3)."""
    eye = torch.eye(3, dtype=R0.dtype, device=R0.device)
    return torch.cat([(eye - R0).flatten(-2), t1, t0], -1)


def pair_features(motion0: Tensor, motionk: Tensor, symmetric: bool = True) -> Tensor:
    """Translation features (..., D, 15) of motion pairs (camera 0's and camera k's motions, (..., 4, 4)):
    D = 1 (the pair as given) or, ``symmetric``, D = 2 (the pair and its reverse)."""
    R0, t0, t1 = motion0[..., :3, :3], motion0[..., :3, 3], motionk[..., :3, 3]
    z = translation_features(R0, t0, t1)
    if not symmetric:
        return z.unsqueeze(-2)
    R0t, R1t = R0.mT, motionk[..., :3, :3].mT
    back = translation_features(R0t, -(R0t @ t0.unsqueeze(-1)).squeeze(-1), -(R1t @ t1.unsqueeze(-1)).squeeze(-1))
    return torch.stack([z, back], -2)


def translation_quadratic(Z: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """The weighted translation residual as a quadratic in ``y = (dT, vec(s dR))`` (row-major ``dR``):
    ``sum w |(I - R0) dT + s dR t1 - t0|^2 = y^T P y - 2 p.y + c``.

    Z: (..., 58) the rows' statistics (:func:`row_statistics`). Returns P (..., 12, 12), p (..., 12), c (...).

    Equation r of a row reads ``E_r . dT + t1 . m_r = t0[r]`` (``E = I - R0``, ``m_r`` row r of ``s dR``), so
    ``P = [[sum E^T E, cross], [cross^T, I (x) sum t1 t1^T]]`` with ``cross[i, 3 r + j] = sum E[r, i] t1[j]``, and
    ``p = (sum E^T t0, sum t0[r] t1[j])``, ``c = sum |t0|^2``.
    """
    A, cross, t1t1 = Z[..., :9].unflatten(-1, (3, 3)), Z[..., 9:36].unflatten(-1, (3, 9)), Z[..., 36:45]
    eye = torch.eye(3, dtype=Z.dtype, device=Z.device)
    D = (eye[:, None, :, None] * t1t1.unflatten(-1, (3, 3))[..., None, :, None, :]).flatten(-4, -3).flatten(-2)
    P = torch.cat([torch.cat([A, cross], -1), torch.cat([cross.mT, D], -1)], -2)
    return P, Z[..., 45:57], Z[..., 57]


def translation_rows(R0: Tensor, t0: Tensor, t1: Tensor, dR: Tensor) -> tuple[Tensor, Tensor]:
    """The explicit rows ``B = [I - R0, dR t1]`` (..., 3, 4) and ``b = t0`` (..., 3)."""
    eye = torch.eye(3, dtype=R0.dtype, device=R0.device)
    return torch.cat([eye - R0, (dR @ t1.unsqueeze(-1))], -1), t0


def normal_equations(quadratic: tuple[Tensor, Tensor, Tensor], maps: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Normal equations of ``(I - R0) dT + sum_k c_k L_k t1 = t0`` for the unknown ``x = (dT, c)``.

    Args:
        quadratic: ``(P, p, c)`` of :func:`translation_quadratic`.
        maps: (..., m, 3, 3) the linear maps ``L_k`` applied to ``t1``. The general model has one map, ``dR`` (unknowns
            ``dT, s``); the planar model has three (see :mod:`ocalib.calib.stages.planar`).

    Returns:
        H (..., 3+m, 3+m), g (..., 3+m), and ``sum w |t0|^2`` (...), so that the weighted residual is
        ``|t0|^2 - 2 x.g + x^T H x``.
    """
    P, p, c = quadratic
    # y = (dT, vec(sum_k c_k L_k)) = J x with J = [[I, 0], [0, vec(L_1) .. vec(L_m)]].
    m = maps.shape[-3]
    eye = torch.eye(3, dtype=P.dtype, device=P.device).expand(*maps.shape[:-3], 3, 3)
    top = torch.cat([eye, P.new_zeros(*maps.shape[:-3], 3, m)], -1)
    bottom = torch.cat([P.new_zeros(*maps.shape[:-3], 9, 3), maps.flatten(-2).mT], -1)
    J = torch.cat([top, bottom], -2)
    return J.mT @ P @ J, (J.mT @ p.unsqueeze(-1)).squeeze(-1), c
