"""Joint robust refinement of one frame's motion from its 2D-2D tracks and its triangulated landmarks.

Residuals, all in pixels: the Sampson distance of every track ``(ba, bb)`` to the epipolar geometry
``E = [t]x R`` (rotation and translation direction; blind to the length of t), and the reprojection error
of every landmark ``X`` (frame a, the trajectory's unit) seen at pixel ``ub`` in frame b (the length of t).
Levenberg-Marquardt with a Cauchy loss (redescending: a wrong track, e.g. one that slipped by a period of a
brick wall, stops pulling) over the 6 parameters ``R <- exp(w) R``, ``t <- t + dt``.

Convention: ``p_b = R p_a + t``; bearings ``K^-1 (u, v, 1)`` with z = 1.
"""

from __future__ import annotations

import cv2
import numpy as np


def residuals(R: np.ndarray, t: np.ndarray, ba, bb, X, ub, K) -> np.ndarray:
    """Sampson distances (N,) then reprojection errors (2L,), pixels."""
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    E = tx @ R
    Ea, Eb = ba @ E.T, bb @ E
    num = (bb * Ea).sum(1)
    den = Ea[:, 0] ** 2 + Ea[:, 1] ** 2 + Eb[:, 0] ** 2 + Eb[:, 1] ** 2
    sampson = 0.5 * (K[0, 0] + K[1, 1]) * num / np.sqrt(np.maximum(den, 1e-30))
    Y = X @ R.T + t
    z = np.maximum(Y[:, 2], 1e-6)
    reproj = np.stack([K[0, 0] * Y[:, 0] / z + K[0, 2] - ub[:, 0], K[1, 1] * Y[:, 1] / z + K[1, 2] - ub[:, 1]], 1)
    reproj = np.where(Y[:, 2:] > 1e-6, reproj, 1e3)  # behind the camera: a large, constant error
    return np.concatenate([sampson, reproj.ravel()])


def robust_cost(r: np.ndarray, c: float) -> float:
    """Sum of Cauchy losses ``c^2 / 2 log(1 + (r / c)^2)`` of residuals r (pixels)."""
    return float(0.5 * c * c * np.log1p((r / c) ** 2).sum())


def _update(R, t, delta):
    return cv2.Rodrigues(delta[:3])[0] @ R, t + delta[3:]


def refine_motion(R, t, ba, bb, X, ub, K, c: float = 1.0, iterations: int = 10):
    """Refine ``(R, t)`` from tracks ``ba``, ``bb`` (N, 3) and landmarks ``X`` (L, 3) seen at ``ub`` (L, 2).

    Returns ``(R, t, cost, r)``: the robust cost (:func:`robust_cost`, scale ``c`` pixels) and the residuals
    (N + 2L,) at the result. Without landmarks (L = 0) the length of t is kept as given.
    """
    length, eps = np.linalg.norm(t), 1e-6
    r = residuals(R, t, ba, bb, X, ub, K)
    cost, lam = robust_cost(r, c), 1e-3
    for _ in range(iterations):
        w = 1.0 / (1.0 + (r / c) ** 2)
        J = np.empty((len(r), 6))
        for k in range(6):
            d = np.zeros(6)
            d[k] = eps
            J[:, k] = (residuals(*_update(R, t, d), ba, bb, X, ub, K) - r) / eps
        H = J.T @ (w[:, None] * J)
        g = J.T @ (w * r)
        improved = False
        while lam < 1e6 and not improved:
            delta = -np.linalg.solve(H + lam * np.diag(np.diag(H)) + 1e-9 * np.eye(6), g)
            R1, t1 = _update(R, t, delta)
            if not len(X):
                t1 = t1 * length / np.linalg.norm(t1)
            r1 = residuals(R1, t1, ba, bb, X, ub, K)
            c1 = robust_cost(r1, c)
            improved = c1 < cost
            lam = max(lam / 10, 1e-7) if improved else lam * 10
        if not improved:
            break
        converged = cost - c1 < 1e-6 * cost
        R, t, r, cost = R1, t1, r1, c1
        if converged:
            break
    return R, t, cost, r
