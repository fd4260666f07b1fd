"""Batch reference solver (Esquivel et al. 2007): the same hand-eye equations, all frames at once.

Used by the tests as the reference of the on-line solvers and by ``--solver batch``. No gating and no
robust weights: every valid motion pair counts once.

Convention: as :mod:`ocalib.calib.online` -- poses (T, C, 4, 4) camera-to-world, camera 0 the reference.
"""

from __future__ import annotations

import torch
from torch import Tensor

from ocalib.calib.handeye import rotation_block, translation_features, translation_rows
from ocalib.calib.online import MOTIONS
from ocalib.calib.rotation import batch_rotation
from ocalib.geometry.pose import invert_pose
from ocalib.geometry.quaternion import quaternion_to_rotation_matrix, rotation_matrix_to_quaternion


def motion_pairs(num_frames: int, motion: str | tuple[int, ...]) -> tuple[Tensor, Tensor]:
    """Frame indices (start, end) of every motion pair of a sequence, in the order the on-line solver
    meets them (by end frame). Gap 0 stands for the pair with frame 0."""
    gaps = MOTIONS[motion] if isinstance(motion, str) else tuple(motion)
    start, end = [], []
    for t in range(num_frames):
        for g in gaps:
            if g > 0 and t - g >= 0:
                start.append(t - g)
                end.append(t)
            elif g == 0 and t > 0:
                start.append(0)
                end.append(t)
    return torch.tensor(start, dtype=torch.long), torch.tensor(end, dtype=torch.long)


def pair_motions(poses: Tensor, start: Tensor, end: Tensor) -> Tensor:
    """Motions ``T_start^-1 T_end`` (M, C, 4, 4) of every camera for pairs of frame indices (M,)."""
    return invert_pose(poses[start]) @ poses[end]


def batch_calibrate(poses: Tensor, motion: str | tuple[int, ...] = "multi") -> dict[str, Tensor]:
    """Batch hand-eye calibration of cameras 1..C-1 against camera 0.

    Args:
        poses: (T, C, 4, 4) camera-to-world poses, float64, all valid.
        motion: the motion pairing (see :data:`ocalib.calib.online.MOTIONS`).

    Returns:
        ``quaternion`` (K, 4), ``rotation`` (K, 3, 3), ``translation`` (K, 3), ``scale`` (K,),
        ``singular_values`` (K, 4), and the stacked ``blocks`` (K, M, 4, 4) and ``features`` (K, M, 15).
    """
    start, end = motion_pairs(poses.shape[0], motion)
    m = pair_motions(poses, start, end)  # (M, C, 4, 4)
    q = rotation_matrix_to_quaternion(m[..., :3, :3])
    q0, q1 = q[:, :1].expand_as(q[:, 1:]), q[:, 1:]
    A = rotation_block(q0, q1).transpose(0, 1)  # (K, M, 4, 4)
    quat, S, _ = batch_rotation(A)
    dR = quaternion_to_rotation_matrix(quat)
    R0, t0, t1 = m[:, :1, :3, :3].expand_as(m[:, 1:, :3, :3]), m[:, :1, :3, 3].expand_as(m[:, 1:, :3, 3]), m[:, 1:, :3, 3]
    B, b = translation_rows(R0, t0, t1, dR.unsqueeze(0))
    B, b = B.transpose(0, 1).flatten(1, 2), b.transpose(0, 1).flatten(1, 2)  # (K, 3M, 4), (K, 3M)
    x = (torch.linalg.pinv(B) @ b.unsqueeze(-1)).squeeze(-1)
    return {
        "quaternion": quat,
        "rotation": dR,
        "translation": x[:, :3],
        "scale": x[:, 3],
        "singular_values": S,
        "blocks": A,
        "features": translation_features(R0, t0, t1).transpose(0, 1),
    }
