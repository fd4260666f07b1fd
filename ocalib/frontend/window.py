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

from ocalib.frontend.window_kernel import normal_equations, project


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
    F, L = len(poses), len(rho)
    free = F - fixed
    frame, landmark = np.ascontiguousarray(frame, np.int64), np.ascontiguousarray(landmark, np.int64)
    a = np.ascontiguousarray(anchor, np.int64)[landmark]
    b = np.ascontiguousarray(bearing[landmark], np.float64)
    K, pixels = np.ascontiguousarray(K, np.float64), np.ascontiguousarray(pixels, np.float64)

    def residual(R, cen, rho):
        """The points (M, 3) in the observing frames and the pixel errors (M, 2)."""
        return project(R, cen, rho, frame, landmark, a, b, K, pixels)

    def cost(r):
        return 0.5 * c * c * np.log1p((r * r).sum(1) / (c * c)).sum()

    Y, r = residual(R, cen, rho)
    best, lam = cost(r), 1e-3
    for _ in range(iterations):
        # Normal equations (compiled: projection, Jacobians and Cauchy IRLS weights per observation, summed in 6x6
        # blocks per frame pair and frame-landmark pair), then the Schur complement on the inverse depths.
        gb, Hpl, Hb, Hll, gl = normal_equations(R, cen, rho, frame, landmark, a, b, K, Y, r, float(c), F)
        Hpp = Hb[fixed:, fixed:].transpose(0, 2, 1, 3).reshape(6 * free, 6 * free)
        gp = gb[fixed:].reshape(-1)
        Hpl = Hpl[fixed:].transpose(0, 2, 1).reshape(6 * free, L)
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
            Y1, r1 = residual(R1, c1, rho1)
            new = cost(r1)
            improved = new < best
            lam = max(lam / 10, 1e-7) if improved else lam * 10
        if not improved:
            break
        done = best - new < 1e-6 * best
        R, cen, rho, Y, r, best = R1, c1, rho1, Y1, r1, new
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
