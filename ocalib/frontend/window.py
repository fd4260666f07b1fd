"""Sliding-window bundle adjustment: the last few frames' poses and their tracks' inverse depths, jointly.

The two oldest frames of the window stay fixed: they pin the gauge, and the distance between them carries
the trajectory's unit into the new frames (scale propagation through every track of the window, not one
frame pair at a time). A landmark is a track's bearing ``b`` in its anchor frame (its first in the window)
with inverse depth ``rho``; frame k sees it along ``Y = R_k^T (R_a b + rho (c_a - c_k))`` (homogeneous:
no division by rho, so far points, rho -> 0, are fine and still fix rotation). Levenberg-Marquardt with a
Cauchy loss on the reprojection errors (pixels) and the Schur complement on the scalar inverse depths.

Convention: poses camera-to-world (4, 4) with ``R_k``, centre ``c_k``; bearings ``K^-1 (u, v, 1)``.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy import sparse

from ocalib.geometry.se3 import cross_matrix


def _project(R, c, frame, anchor, b, rho, K):
    """Homogeneous points Y (M, 3) in the observing frames and their pixels (M, 2)."""
    Ra, ca, Rk, ck = R[anchor], c[anchor], R[frame], c[frame]
    Y = np.einsum("mji,mj->mi", Rk, np.einsum("mij,mj->mi", Ra, b) + rho[:, None] * (ca - ck))
    z = np.where(np.abs(Y[:, 2]) > 1e-9, Y[:, 2], 1e-9)
    return Y, np.stack([K[0, 0] * Y[:, 0] / z + K[0, 2], K[1, 1] * Y[:, 1] / z + K[1, 2]], 1)


def _inner(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A^T B`` (M, p, q) of A (M, 2, p) and B (M, 2, q), its two terms written out (a third of einsum's time)."""
    out = A[:, 0, :, None] * B[:, 0, None, :]
    out += A[:, 1, :, None] * B[:, 1, None, :]
    return out if B.shape[2] > 1 else out[..., 0]


def _summing(keys: list[np.ndarray], size: int) -> sparse.csr_matrix:
    """The sparse (size, N) matrix that sums rows (N, D) of arrays stacked in the order of ``keys`` (each (M,)) by
    their keys, each sum in the rows' order: what ``np.add.at`` into zeros gives, many times faster."""
    keys = np.concatenate(keys)
    return sparse.csr_matrix((np.ones(len(keys)), (keys, np.arange(len(keys)))), shape=(size, len(keys)))


def bundle_adjust(poses, fixed: int, frame, landmark, pixels, anchor, bearing, rho, K, c: float = 1.0,
                  iterations: int = 5):  # fmt: skip
    """Refine window poses (F, 4, 4) and inverse depths rho (L,) from observations.

    Args:
        poses: (F, 4, 4) camera-to-world; frames ``< fixed`` are held. frame, landmark: (M,) the frame and
            landmark index of each observation (never its anchor), pixels (M, 2). anchor (L,) frame index
            and bearing (L, 3) of each landmark; rho (L,) initial inverse depths. c: Cauchy scale, pixels.
    Returns:
        ``(poses (F, 4, 4), rho (L,), residual (M,) pixel error per observation)``.
    """
    R, cen, rho = poses[:, :3, :3].copy(), poses[:, :3, 3].copy(), rho.astype(np.float64).copy()
    F, L, M = len(poses), len(rho), len(frame)
    free = F - fixed
    a = anchor[landmark]
    b = bearing[landmark]

    def residual(R, cen, rho):
        return _project(R, cen, frame, a, b, rho[landmark], K)[1] - pixels

    def cost(r):
        return 0.5 * c * c * np.log1p((r * r).sum(1) / (c * c)).sum()

    sides = (frame, a)  # the observing frame's and the anchor's blocks, summed by frame (pair) and landmark
    sum_g, sum_pl = _summing(list(sides), F), _summing([f * L + landmark for f in sides], F * L)
    sum_b = _summing([f * F + f2 for f in sides for f2 in sides], F * F)
    r = residual(R, cen, rho)
    best, lam = cost(r), 1e-3
    for _ in range(iterations):
        Y, _ = _project(R, cen, frame, a, b, rho[landmark], K)
        z = Y[:, 2]
        P = np.zeros((M, 2, 3))  # d pixel / d Y
        P[:, 0, 0], P[:, 0, 2] = K[0, 0] / z, -K[0, 0] * Y[:, 0] / z**2
        P[:, 1, 1], P[:, 1, 2] = K[1, 1] / z, -K[1, 1] * Y[:, 1] / z**2
        PRkT = P @ np.swapaxes(R[frame], 1, 2)
        J_rho = PRkT @ (cen[a] - cen[frame])[..., None]  # (M, 2, 1)
        J_k = np.concatenate([P @ cross_matrix(Y), -rho[landmark, None, None] * PRkT], 2)  # observing frame
        J_a = np.concatenate([-(PRkT @ R[a] @ cross_matrix(b)), rho[landmark, None, None] * PRkT], 2)  # anchor
        w = 1.0 / (1.0 + (r * r).sum(1) / (c * c))  # Cauchy IRLS weight per observation
        # Normal equations, accumulated per observation in 6x6 blocks (products written out and sparse sums: no
        # BLAS threads, which spin badly on a busy machine), then the Schur complement on the inverse depths.
        Js, wr = (J_k, J_a), w[:, None] * r
        Jw = [J * w[:, None, None] for J in Js]
        gb = sum_g @ np.concatenate([_inner(J, wr[..., None]) for J in Js])
        Hpl = (sum_pl @ np.concatenate([_inner(Jwi, J_rho) for Jwi in Jw])).reshape(F, L, 6)
        Hb = (sum_b @ np.concatenate([_inner(Jwi, J).reshape(M, 36) for Jwi in Jw for J in Js])).reshape(F, F, 6, 6)
        Hpp = Hb[fixed:, fixed:].transpose(0, 2, 1, 3).reshape(6 * free, 6 * free)
        gp = gb[fixed:].reshape(-1)
        Hpl = Hpl[fixed:].transpose(0, 2, 1).reshape(6 * free, L)
        Hll = np.bincount(landmark, w * (J_rho[:, :, 0] ** 2).sum(1), L)
        gl = np.bincount(landmark, w * (J_rho[:, :, 0] * r).sum(1), L)
        improved = False
        while not improved and lam < 1e6:
            Hll_d = Hll * (1 + lam) + 1e-9
            Hpp_d = Hpp + lam * np.diag(np.diag(Hpp)) + 1e-9 * np.eye(6 * free)
            S = Hpp_d - np.einsum("pl,ql->pq", Hpl / Hll_d, Hpl)
            dp = -np.linalg.solve(S, gp - np.einsum("pl,l->p", Hpl, gl / Hll_d))
            dl = -(gl + np.einsum("pl,p->l", Hpl, dp)) / Hll_d
            R1, c1 = R.copy(), cen.copy()
            for f in range(fixed, F):
                d = dp[6 * (f - fixed) : 6 * (f - fixed) + 6]
                R1[f] = R[f] @ cv2.Rodrigues(d[:3])[0]
                c1[f] = cen[f] + d[3:]
            rho1 = rho + dl
            r1 = residual(R1, c1, rho1)
            new = cost(r1)
            improved = new < best
            lam = max(lam / 10, 1e-7) if improved else lam * 10
        if not improved:
            break
        done = best - new < 1e-6 * best
        R, cen, rho, r, best = R1, c1, rho1, r1, new
        if done:
            break
    out = poses.copy()
    out[:, :3, :3], out[:, :3, 3] = R, cen
    return out, rho, np.linalg.norm(r, axis=1)


def window_problem(history, poses, K, min_views: int = 3):
    """The bundle-adjustment problem of a track history: landmarks are the tracks seen in ``min_views`` or
    more of the window's frames, anchored in the first of them.

    history: per window frame (oldest first), ``(frame, ids (M_f,) sorted, pixels (M_f, 2))``; poses (F, 4, 4)
    camera-to-world of those frames. Returns ``(ids (L,), frame, landmark, pixels, anchor, bearing, rho)`` in
    the layout of :func:`bundle_adjust`, rho from two-ray triangulation (anchor and latest view; 0 when the
    rays do not meet in front of both cameras).
    """
    ids = np.concatenate([h[1] for h in history])
    index = np.concatenate([np.full(len(h[1]), f) for f, h in enumerate(history)])
    px = np.concatenate([h[2] for h in history]).astype(np.float64)
    uniq, inverse, counts = np.unique(ids, return_inverse=True, return_counts=True)
    keep = counts[inverse] >= min_views
    ids, index, px, inverse = ids[keep], index[keep], px[keep], inverse[keep]
    lm_ids, landmark = np.unique(inverse, return_inverse=True)
    order = np.lexsort((index, landmark))  # by landmark, then frame
    ids, index, px, landmark = ids[order], index[order], px[order], landmark[order]
    first = np.r_[True, landmark[1:] != landmark[:-1]]
    last = np.r_[landmark[1:] != landmark[:-1], True]
    anchor, anchor_px = index[first], px[first]
    bearing = np.stack([(anchor_px[:, 0] - K[0, 2]) / K[0, 0], (anchor_px[:, 1] - K[1, 2]) / K[1, 1],
                        np.ones(len(anchor))], 1)  # fmt: skip
    latest, latest_px = index[last], px[last]
    b_k = np.stack([(latest_px[:, 0] - K[0, 2]) / K[0, 0], (latest_px[:, 1] - K[1, 2]) / K[1, 1],
                    np.ones(len(latest))], 1)  # fmt: skip
    rho = _init_rho(poses[anchor], bearing, poses[latest], b_k)
    return ids[first], index[~first], landmark[~first], px[~first], anchor, bearing, rho


def _init_rho(Pa, ba, Pk, bk) -> np.ndarray:
    """Inverse depth (L,) along ``ba`` (z = 1) in frames Pa (L, 4, 4) of the rays' closest approach to the rays
    ``bk`` from Pk; 0 where the rays are (nearly) parallel or meet behind a camera."""
    da = np.einsum("lij,lj->li", Pa[:, :3, :3], ba)
    dk = np.einsum("lij,lj->li", Pk[:, :3, :3], bk)
    w = Pk[:, :3, 3] - Pa[:, :3, 3]
    aa, ak, kk = (da * da).sum(1), (da * dk).sum(1), (dk * dk).sum(1)
    ra, rk = (da * w).sum(1), (dk * w).sum(1)
    det = aa * kk - ak * ak
    ok = det > 1e-9 * aa * kk
    det = np.where(ok, det, 1.0)
    la = (kk * ra - ak * rk) / det  # depth along ba (z = 1): the landmark is c_a + la * R_a ba
    lk = (ak * ra - aa * rk) / det
    return np.where(ok & (la > 0) & (lk > 0), 1.0 / np.maximum(la, 1e-9), 0.0)
