"""Classical monocular visual odometry with OpenCV: the ``--frontend opencv`` of ``ocalib calibrate``.

Per frame:

1. KLT tracks (:class:`~ocalib.frontend.tracker.KLTTracker`: Shi-Tomasi corners, pyramidal Lucas-Kanade from
   a constant-velocity prediction, forward-backward check, replenished corners).
2. Candidate motions: an essential matrix (RANSAC, ``recoverPose``) whose translation gets the median length
   voted by the landmarks, and a PnP pose on the landmarks. Landmarks are the tracks triangulated between the
   oldest of the last ``scale_window`` frames that saw them and the previous frame, with poses already in the
   trajectory's unit: this is how the scale propagates.
3. Both candidates refined on every track's Sampson error and every landmark's reprojection error (Cauchy
   loss, :mod:`~ocalib.frontend.refine`); the cheaper one wins (PnP resolves the rotation/translation
   ambiguity of a planar scene, e.g. a wall, that two views cannot).
4. Degeneracy: too few tracks or inliers, or a median rotation-compensated flow below ``min_parallax`` px,
   flags the frame; without landmarks the motion is then rotation-only (t = 0). With too few tracks (the view
   blocked, or a blank wall close by) the frame is lost: its step is the last measured one again (constant
   velocity; none before the first), as a rotation fitted to a handful of tracks is off by degrees.
5. A sliding-window bundle adjustment (:mod:`~ocalib.frontend.window`) over the last ``scale_window`` frames,
   the oldest ``window_fixed`` held: the returned step is the adjusted motion from the previous frame.

The first moving pair sets the unit (|t| = 1); it is then propagated, never re-normalised.

Convention: ``step`` returns ``T_prev_cur`` (4, 4) float64, the pose of the current frame in the previous
frame's camera frame (``p_prev = R p_cur + t``); ``pose`` is camera-to-first-frame (``p_first = R p_cur + t``).
Camera frame x right, y down, z forward; K (3, 3) pixels with integer pixel centres.
"""

from __future__ import annotations

from collections import deque
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

from ocalib.errors import InputError
from ocalib.frontend.refine import refine_motion
from ocalib.frontend.tracker import KLTTracker
from ocalib.frontend.twoview import (
    bearings,
    essential_motion,
    parallax_px,
    pnp_motion,
    rotation_from_bearings,
    scale_along,
    triangulate,
)
from ocalib.frontend.window import bundle_adjust, window_problem

METHODS = {"ransac": cv2.RANSAC, "lmeds": cv2.LMEDS, "magsac": cv2.USAC_MAGSAC, "usac": cv2.USAC_ACCURATE}
TRACKER_OPTIONS = ("max_features", "quality", "min_distance", "win_size", "levels", "fb_threshold", "predict_levels")


@dataclass
class VOStatus:
    """What one frame's step saw. ``degenerate``: no reliable translation direction (see ``reason``); the step
    is then rotation-only (t = 0), or, when landmarks measured it, a small translation; a lost frame's (``reason``
    "too few tracks") is the last measured step again. ``scale_points``:
    landmarks that fixed the translation's length (0 when it was set otherwise: the first moving pair sets
    the unit, or the previous step's length is kept when too few tracks were old enough)."""

    frame: int
    tracked: int = 0  # tracks followed from the previous frame (forward-backward consistent)
    inliers: int = 0  # tracks consistent with the final motion
    parallax_px: float = 0.0  # median rotation-compensated flow of the inliers, pixels
    scale_points: int = 0
    degenerate: bool = True
    reason: str = "first frame"


class OpenCVOdometry:
    """Monocular VO for one camera with intrinsics ``K`` (3, 3) float64, pixels; one ``step`` per frame.

    Images: numpy (H, W) or (H, W, 3) RGB, uint8 or float in [0, 1]; torch tensors (H, W), (1, H, W) or
    (3, H, W) (ocalib's channel-first convention). Every frame must have the first frame's size.

    Options: the tracker's (:class:`~ocalib.frontend.tracker.KLTTracker`: ``max_features``, ``quality``,
    ``min_distance``, ``win_size``, ``levels``, ``fb_threshold``, ``predict_levels``);
    ``ransac_threshold`` (px at 640 px image width, scaled with the width; also the robust loss scale and,
    x2, the PnP threshold), ``prob`` and ``method`` (usac | ransac | magsac | lmeds) of the essential matrix;
    a step is degenerate below ``min_tracks`` tracks, ``min_inliers`` inliers or ``min_parallax`` px of median
    rotation-compensated flow; ``scale_window`` frames of track history for the landmarks and the bundle
    adjustment, ``min_scale_points`` landmarks to measure the length of t, ``min_triangulation_deg`` of ray
    angle for a track to become a landmark; ``window`` turns the bundle adjustment on, ``window_fixed`` of its
    oldest frames are held (they carry the scale).

    Attributes: ``pose`` (4, 4) camera-to-first-frame after the last step; ``status`` (:class:`VOStatus`).
    """

    def __init__(self, K, ransac_threshold: float = 1.0, prob: float = 0.999, method: str = "usac",
                 min_tracks: int = 20, min_inliers: int = 15, min_parallax: float = 0.3, scale_window: int = 15,
                 min_scale_points: int = 8, min_triangulation_deg: float = 0.5, window: bool = True,
                 window_fixed: int = 6, **tracker):  # fmt: skip
        K = np.asarray(K, dtype=np.float64)
        if K.shape != (3, 3) or not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
            raise InputError(f"intrinsics K must be a finite (3, 3) matrix with fx, fy > 0, got shape {K.shape}")
        if method not in METHODS:
            raise InputError(f"unknown essential-matrix method {method!r} (methods: {', '.join(METHODS)})")
        unknown = set(tracker) - set(TRACKER_OPTIONS)
        if unknown:
            raise InputError(f"unknown VO option(s) {', '.join(sorted(unknown))}")
        if scale_window < 2 or window_fixed < 2:
            raise InputError(f"scale_window and window_fixed must be >= 2, got {scale_window}, {window_fixed}")
        self.K = K
        self.tracker = KLTTracker(**tracker)
        self.ransac_threshold, self.prob, self.method = ransac_threshold, prob, METHODS[method]
        self.min_tracks, self.min_inliers, self.min_parallax = min_tracks, min_inliers, min_parallax
        self.min_scale_points, self.min_angle = min_scale_points, np.radians(min_triangulation_deg)
        self.window, self.window_fixed = window, window_fixed
        self.pose = np.eye(4)
        self.status = VOStatus(frame=-1, reason="no frame yet")
        self._poses: dict[int, np.ndarray] = {}  # frame -> camera-to-first pose, for the landmark window
        self._history: deque = deque(maxlen=scale_window + 1)  # (frame, ids, pixels) after each step
        self._shape: tuple | None = None
        self._speed: float | None = None  # length of the last translation; None until the unit is set
        self._velocity = np.eye(4)  # T_cur_prev of the last step measured (not degenerate), a lost frame's step
        self._frame = 0

    def step(self, image) -> np.ndarray:
        """Add the next frame; returns ``T_prev_cur`` (4, 4) float64 (identity for the first frame)."""
        n = self._frame
        grey = to_grey(image, n)
        if self._shape is None:
            self._shape = grey.shape
        elif grey.shape != self._shape:
            raise InputError(f"frame {n}: image size {grey.shape} differs from the first frame's {self._shape}")
        ids, pa, pb = self.tracker.track(grey)
        if n == 0:
            self.status = VOStatus(frame=0)
            self._poses[0] = np.eye(4)
        else:
            R, t, self.status = self._motion(n, ids, pa.astype(np.float64), pb.astype(np.float64))
            step = np.eye(4)
            step[:3, :3], step[:3, 3] = R.T, -R.T @ t  # (R, t) is T_cur_prev
            self._poses[n] = self._poses[n - 1] @ step
        self._poses.pop(n - self._history.maxlen, None)
        self.tracker.replenish()
        self._history.append((n, self.tracker.ids.copy(), self.tracker.points.astype(np.float64)))
        if self.window and self.status.scale_points:
            self._adjust()
        T = np.linalg.inv(self._poses[n - 1]) @ self._poses[n] if n else np.eye(4)
        if not self.status.degenerate:
            self._velocity = np.linalg.inv(T)
        self.pose = self.pose @ T
        self._frame += 1
        return T

    def _adjust(self) -> None:
        """Bundle-adjust the window (its ``window_fixed`` oldest frames held) and drop the tracks it rejects."""
        history = list(self._history)
        if len(history) < 4:
            return
        poses = np.stack([self._poses[h[0]] for h in history])
        ids, frame, landmark, px, anchor, bearing, rho = window_problem(history, poses, self.K)
        if len(ids) < self.min_scale_points:
            return
        c = self.ransac_threshold * self._shape[1] / 640.0
        fixed = min(self.window_fixed, len(history) - 1)
        poses, _, err = bundle_adjust(poses, fixed, frame, landmark, px, anchor, bearing, rho, self.K, c)
        if not np.isfinite(poses).all():
            return
        for h, P in zip(history, poses):
            self._poses[h[0]] = P
        self._speed = float(np.linalg.norm(poses[-1, :3, 3] - poses[-2, :3, 3]))
        bad = ids[np.unique(landmark[(frame == len(history) - 1) & (err > 3 * c)])]
        if len(bad):
            self.tracker.keep(~np.isin(self.tracker.ids, bad))

    def _motion(self, n: int, ids, pa, pb) -> tuple[np.ndarray, np.ndarray, VOStatus]:
        """``(R, t, status)`` of frame n with ``p_cur = R p_prev + t``, from the tracks (ids, pa -> pb)."""
        status = VOStatus(frame=n, tracked=len(ids))
        ba, bb = bearings(pa, self.K), bearings(pb, self.K)
        px = self.ransac_threshold * self._shape[1] / 640.0
        if len(ids) < self.min_tracks:  # lost: the last measured step again (constant velocity), else none
            status.reason = "too few tracks"
            return self._velocity[:3, :3], self._velocity[:3, 3], status
        found = essential_motion(pa, pb, self.K, px, self.prob, self.method)
        if found is None or found[2].sum() < self.min_inliers:  # no two-view geometry: rotation only
            R = rotation_from_bearings(ba, bb) if len(ids) >= 3 else np.eye(3)
            status.inliers = 0 if found is None else int(found[2].sum())
            status.parallax_px = float(np.median(parallax_px(ba, bb, R, self.K))) if len(ids) else 0.0
            status.reason = "low parallax" if status.parallax_px < self.min_parallax else "too few inliers"
            return R, np.zeros(3), status
        R, t, inl = found
        idx, X = self._landmarks(ids) if self._speed is not None else (np.zeros(0, int), np.zeros((0, 3)))
        candidates = [(R, t * self._initial_length(X, bb[idx], R, t))]
        if len(idx) >= self.min_scale_points:
            pnp = pnp_motion(X, pb[idx], self.K, 2 * px, self.prob)
            if pnp is not None and pnp[2].sum() >= self.min_scale_points:
                candidates.append(pnp[:2])
        if len(idx) < self.min_scale_points:
            idx, X = idx[:0], X[:0]
        R, t, _, r = min((refine_motion(*c, ba, bb, X, pb[idx], self.K, px) for c in candidates), key=lambda x: x[2])
        if not (np.isfinite(R).all() and np.isfinite(t).all() and np.isfinite(r).all()):
            status.reason = "no finite motion"
            return rotation_from_bearings(ba[inl], bb[inl]), np.zeros(3), status
        good = np.abs(r[: len(ids)]) < 3 * px  # tracks consistent with the motion
        status.inliers = int(good.sum())
        status.parallax_px = float(np.median(parallax_px(ba[good], bb[good], R, self.K))) if good.any() else 0.0
        reproj = np.abs(r[len(ids) :].reshape(-1, 2)).max(1) if len(idx) else np.zeros(0)
        status.scale_points = int((reproj < 3 * px).sum())
        if status.scale_points < self.min_scale_points:
            status.scale_points = 0
        if status.inliers < self.min_inliers or status.parallax_px < self.min_parallax:
            # No reliable direction. Landmarks still measure a small translation; two views alone do not.
            status.reason = "too few inliers" if status.inliers < self.min_inliers else "low parallax"
            if not status.scale_points:
                return rotation_from_bearings(ba[good], bb[good]) if good.sum() >= 3 else R, np.zeros(3), status
        else:
            status.degenerate, status.reason = False, ""
        if self._speed is None:  # the first moving pair sets the unit
            t = t / np.linalg.norm(t)
        elif not status.scale_points:
            status.reason = status.reason or "scale from the previous step"
        self._speed = float(np.linalg.norm(t))
        self.tracker.keep(good)
        return R, t, status

    def _initial_length(self, X, bb, R, t) -> float:
        """Length of t for the essential-matrix candidate: median of the landmarks' votes, else the last one."""
        if self._speed is None:
            return 1.0
        votes, sin = scale_along(X, bb, R, t)
        votes = votes[sin > 0.05]
        return float(np.median(votes)) if len(votes) >= self.min_scale_points else self._speed

    def _landmarks(self, ids) -> tuple[np.ndarray, np.ndarray]:
        """Tracks ``ids`` (M,) triangulated between the oldest frame of the window that saw them and the previous
        frame, in the previous frame's camera frame and the trajectory's unit: ``(index into ids (L,), points
        (L, 3))``, only those whose rays meet at ``min_triangulation_deg`` or more."""
        prev_frame, prev_ids, prev_px = self._history[-1]
        oldest = np.full(len(ids), -1)
        oldest_px = np.zeros((len(ids), 2))
        for frame, f_ids, f_px in list(self._history)[:-1]:  # oldest first
            if not len(f_ids):
                continue
            pos = np.searchsorted(f_ids, ids).clip(0, len(f_ids) - 1)
            hit = (oldest < 0) & (f_ids[pos] == ids)
            oldest[hit], oldest_px[hit] = frame, f_px[pos[hit]]
        prev_b = bearings(prev_px[np.searchsorted(prev_ids, ids)], self.K)
        index, points = [np.zeros(0, int)], [np.zeros((0, 3))]
        for frame in np.unique(oldest[oldest >= 0]):
            sel = np.flatnonzero(oldest == frame)
            T = np.linalg.inv(self._poses[frame]) @ self._poses[prev_frame]  # p_old = T p_prev
            X, angle = triangulate(prev_b[sel], bearings(oldest_px[sel], self.K), T[:3, :3], T[:3, 3])
            good = angle > self.min_angle
            index.append(sel[good])
            points.append(X[good])
        return np.concatenate(index), np.concatenate(points)


def to_grey(image, n: int) -> np.ndarray:
    """Frame n as 8-bit grey (H, W); InputError naming the frame on a bad image."""
    if hasattr(image, "detach"):  # torch: channel-first
        image = image.detach().cpu().numpy()
        if image.ndim == 3 and image.shape[0] in (1, 3):
            image = np.moveaxis(image, 0, -1)
    image = np.asarray(image)
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[..., 0]
    if not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 3)):
        raise InputError(f"frame {n}: expected an image (H, W) or (H, W, 3), got shape {image.shape}")
    if min(image.shape[:2]) < 16:
        raise InputError(f"frame {n}: image {image.shape[:2]} is too small (at least 16 x 16 pixels)")
    if image.dtype != np.uint8:
        if not np.issubdtype(image.dtype, np.floating):
            raise InputError(f"frame {n}: expected uint8 or float in [0, 1], got {image.dtype}")
        if not np.isfinite(image).all() or image.min() < -1e-3 or image.max() > 1 + 1e-3:
            raise InputError(f"frame {n}: float image values must be finite and in [0, 1]")
        image = np.clip(image * 255.0 + 0.5, 0, 255).astype(np.uint8)
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    return np.ascontiguousarray(image)


def run_opencv_vo(images, K, progress: bool = False, **options) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Run :class:`OpenCVOdometry` over a sequence of images (arrays, or image file paths).

    Returns ``poses`` (N, 4, 4) float64 camera-to-first-frame, and the per-frame flags: a dict of (N,)
    arrays with the fields of :class:`VOStatus` (``degenerate``, ``tracked``, ``inliers``, ``parallax_px``,
    ``scale_points``, ``reason``). Errors name the file (paths) or the frame (arrays).
    """
    vo = OpenCVOdometry(K, **options)
    poses, status = [], []
    if progress:
        from tqdm import tqdm

        images = tqdm(images, desc="opencv vo", unit="frame")
    for n, image in enumerate(images):
        if isinstance(image, (str, Path)):
            path = image
            image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
            if image is None:
                raise InputError(f"{path}: cannot read the image (frame {n})")
            try:
                vo.step(image)
            except InputError as err:
                raise InputError(f"{path}: {err}") from None
        else:
            vo.step(image)
        poses.append(vo.pose)
        status.append(asdict(vo.status))
    if not poses:
        raise InputError("no images: the sequence is empty")
    flags = {k: np.array([s[k] for s in status]) for k in status[0] if k != "frame"}
    return np.stack(poses), flags
