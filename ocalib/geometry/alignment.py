"""Similarity (Sim(3)) alignment of trajectories, numpy: Umeyama's closed form, and the scale it finds.

Convention: poses are camera-to-world 4x4 float64 (numpy). ``umeyama(src, dst)`` returns (s, R, t) with
``dst ~ s R src + t``; :func:`align_poses` applies such a transform to poses, so an aligned predicted
pose maps the predicted camera into the ground-truth world: ``R' = R R_i``, ``t' = s R t_i + t``.
"""

from __future__ import annotations

import math

import numpy as np

from ocalib.errors import InputError


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = True) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity from points ``src`` (N, 3) to ``dst`` (N, 3) -> (s, R (3, 3), t (3,)).

    Minimises ``sum ||dst_i - (s R src_i + t)||^2`` over rotations R (det +1), s > 0 and t (Umeyama 1991,
    eqs. 40-42). ``with_scale=False`` fixes s = 1 (SE(3) alignment). Raises InputError when ``src`` has no
    spread (all points equal: the scale is undefined).
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3:
        raise InputError(f"umeyama: need two (N, 3) point sets of equal shape, got {src.shape} and {dst.shape}")
    mu_src, mu_dst = src.mean(0), dst.mean(0)
    x, y = src - mu_src, dst - mu_dst
    var_src = (x**2).sum(1).mean()
    if var_src <= 1e-24 * max(1.0, (mu_src**2).sum()):
        raise InputError(f"umeyama: the {len(src)} source points are all at the same place (no motion to align)")
    cov = y.T @ x / len(src)  # Sigma_xy of the paper: (dst - mu) (src - mu)^T
    U, D, Vt = np.linalg.svd(cov)
    S = np.ones(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2] = -1
    R = U @ np.diag(S) @ Vt
    s = float((D * S).sum() / var_src) if with_scale else 1.0
    t = mu_dst - s * R @ mu_src
    return s, R, t


def align_poses(poses: np.ndarray, s: float, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Apply the similarity (s, R, t) to camera-to-world poses (N, 4, 4): rotations R R_i, positions s R t_i + t."""
    out = np.array(poses, dtype=np.float64, copy=True)
    out[:, :3, :3] = R @ out[:, :3, :3]
    out[:, :3, 3] = s * out[:, :3, 3] @ R.T + t
    return out


def align_trajectory(pred: np.ndarray, gt: np.ndarray, with_scale: bool = True) -> tuple[np.ndarray, dict]:
    """Align predicted poses (N, 4, 4) to ground truth (N, 4, 4) by their camera positions.

    Returns the aligned predicted poses and ``{"scale", "rotation", "translation"}`` of the transform.
    """
    s, R, t = umeyama(pred[:, :3, 3], gt[:, :3, 3], with_scale)
    return align_poses(pred, s, R, t), {"scale": s, "rotation": R, "translation": t}


def trajectory_scale(estimate: np.ndarray, truth: np.ndarray) -> float:
    """The factor that brings the positions of ``estimate`` (T, 4, 4) to those of ``truth`` (T, 4, 4) (to metres):
    the scale of the Sim(3) (Umeyama) fit of its finite positions; NaN when either does not move."""
    valid = np.isfinite(estimate).all((1, 2)) & np.isfinite(truth).all((1, 2))
    moves = lambda p: np.ptp(p[valid, :3, 3], 0).max() > 0  # noqa: E731
    if valid.sum() < 3 or not moves(truth) or not moves(estimate):
        return math.nan
    scale, _, _ = umeyama(estimate[valid, :3, 3], truth[valid, :3, 3])
    return scale
