"""Two-view geometry (and PnP) on bearing vectors for the classical front end (numpy, float64).

Convention: a bearing ``b = K^-1 (u, v, 1)`` (not normalised, z = 1) in its camera's frame (x right, y down,
z forward). A relative motion ``(R, t)`` maps points of camera a into camera b: ``p_b = R p_a + t``
(OpenCV's ``recoverPose`` convention), i.e. ``[R t]`` is ``T_b_a``.
"""

from __future__ import annotations

import cv2
import numpy as np

FAR = 1e6  # recoverPose distance threshold, in baselines


def bearings(points: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Pixels (N, 2) -> bearings (N, 3) with z = 1."""
    x = (points[:, 0] - K[0, 2]) / K[0, 0]
    y = (points[:, 1] - K[1, 2]) / K[1, 1]
    return np.stack([x, y, np.ones_like(x)], 1)


def essential_motion(pa: np.ndarray, pb: np.ndarray, K: np.ndarray, threshold: float, prob: float, method: int):
    """Relative motion of camera b from pixels ``pa``, ``pb`` (N, 2): RANSAC essential matrix + recoverPose.

    Returns ``(R (3, 3), t (3,) unit, inliers (N,) bool)``, or None when OpenCV finds no model.
    ``threshold`` in pixels; ``inliers`` are the RANSAC inliers. The cheirality vote counts points out to
    ``FAR`` baselines (OpenCV's default of 50 would drop most points of a slowly moving camera).
    """
    try:
        E, mask = cv2.findEssentialMat(pa, pb, K, method=method, prob=prob, threshold=threshold)
        if E is None or mask is None or E.shape[0] < 3:
            return None
        inliers = mask[:, 0] > 0
        n, R, t, _, _ = cv2.recoverPose(E[:3], pa, pb, K, distanceThresh=FAR, mask=mask.copy())  # several: the first
    except cv2.error:  # degenerate input trips OpenCV's assertions
        return None
    if n < 5 or not np.isfinite(t).all():
        return None
    return R, t[:, 0] / np.linalg.norm(t), inliers


def rotation_from_bearings(ba: np.ndarray, bb: np.ndarray) -> np.ndarray:
    """Rotation R (3, 3) minimising ``sum |bb_hat - R ba_hat|^2`` over unit bearings (Kabsch): the motion of
    a purely rotating camera."""
    ua = ba / np.linalg.norm(ba, axis=1, keepdims=True)
    ub = bb / np.linalg.norm(bb, axis=1, keepdims=True)
    U, _, Vt = np.linalg.svd(ub.T @ ua)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def parallax_px(ba: np.ndarray, bb: np.ndarray, R: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Rotation-compensated flow (N,) in pixels: how far each point of b is from where a pure rotation R
    would have put the point of a. Zero for a rotating camera (or points at infinity)."""
    r = ba @ R.T
    with np.errstate(divide="ignore", invalid="ignore"):
        d = r[:, :2] / r[:, 2:] - bb[:, :2]
    d = np.where(r[:, 2:] > 1e-6, d, np.inf)
    return np.hypot(d[:, 0] * K[0, 0], d[:, 1] * K[1, 1])


def triangulate(ba: np.ndarray, bb: np.ndarray, R: np.ndarray, t: np.ndarray):
    """Midpoint triangulation of rays ``ba`` (camera a) and ``bb`` (camera b), ``p_b = R p_a + t``.

    Returns points (N, 3) in camera a's frame and the angle (N,) between the rays in radians (the
    parallax: small angle, poor depth). Points behind either camera get angle 0.
    """
    da = ba / np.linalg.norm(ba, axis=1, keepdims=True)
    db = (bb / np.linalg.norm(bb, axis=1, keepdims=True)) @ R  # ray b in frame a (R^T db)
    cb = -R.T @ t  # centre of b in frame a
    # Solve la da - lb db = cb (least squares, 2 unknowns per point).
    a11 = np.ones(len(da))
    a12 = -(da * db).sum(1)
    a22 = np.ones(len(da))
    r1 = da @ cb
    r2 = -(db @ cb)
    det = a11 * a22 - a12 * a12
    ok = det > 1e-12
    det = np.where(ok, det, 1.0)
    la = (a22 * r1 - a12 * r2) / det
    lb = (a11 * r2 - a12 * r1) / det
    points = 0.5 * (la[:, None] * da + (cb + lb[:, None] * db))
    angle = np.arccos(np.clip((da * db).sum(1), -1.0, 1.0))
    angle = np.where(ok & (la > 0) & (lb > 0), angle, 0.0)
    return points, angle


def scale_along(points: np.ndarray, bb: np.ndarray, R: np.ndarray, t: np.ndarray):
    """Per point, the scale s that makes camera b (``p_b = R p_a + s t``) see ``points`` (N, 3, frame a)
    along bearings ``bb`` (N, 3): least squares of ``bb x (R p + s t) = 0``.

    Returns ``(s (N,), sin (N,))``: ``sin`` is the sine of the angle between the bearing and t, the
    conditioning of each estimate (0 at the epipole, where the point says nothing about s).
    """
    u = bb / np.linalg.norm(bb, axis=1, keepdims=True)
    c_t = np.cross(u, t)
    c_p = np.cross(u, points @ R.T)
    nt = (c_t * c_t).sum(1)
    s = -(c_p * c_t).sum(1) / np.maximum(nt, 1e-18)
    return s, np.sqrt(nt)


def pnp_motion(points: np.ndarray, pixels: np.ndarray, K: np.ndarray, threshold: float, prob: float):
    """Pose of camera b from points (N, 3) of frame a and their pixels (N, 2) in b: RANSAC PnP (SQPnP on
    minimal samples) refined by Levenberg-Marquardt on the inliers. ``(R, t, inliers (N,) bool)`` with
    ``p_b = R p_a + t``, or None."""
    X, u = np.ascontiguousarray(points, np.float64), np.ascontiguousarray(pixels, np.float64)
    try:
        ok, rvec, tvec, inl = cv2.solvePnPRansac(X, u, K, None, iterationsCount=200, reprojectionError=threshold,
                                                 confidence=prob, flags=cv2.SOLVEPNP_SQPNP)  # fmt: skip
        if not ok or inl is None or len(inl) < 6:
            return None
        inliers = np.zeros(len(X), bool)
        inliers[inl[:, 0]] = True
        rvec, tvec = cv2.solvePnPRefineLM(X[inliers], u[inliers], K, None, rvec, tvec)
    except cv2.error:  # e.g. SQPnP's assertion on (nearly) collinear or coincident points
        return None
    if not (np.isfinite(rvec).all() and np.isfinite(tvec).all()):
        return None
    return cv2.Rodrigues(rvec)[0], tvec[:, 0], inliers
