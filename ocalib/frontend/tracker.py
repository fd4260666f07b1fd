"""Sparse KLT feature tracks with persistent ids: Shi-Tomasi corners followed by pyramidal Lucas-Kanade from
a constant-velocity prediction, a forward-backward check, and new corners where the tracks thin out.

Convention: pixel coordinates (u, v) with integer pixel centres (OpenCV's and kornia's), float32.
"""

from __future__ import annotations

import cv2
import numpy as np


class KLTTracker:
    """Tracks corners from frame to frame on 8-bit grey images (H, W).

    ``track(grey)`` returns the tracks seen in both the previous and this frame; ``keep(mask)`` drops
    tracks (e.g. outliers of the motion); ``replenish()`` adds corners away from the surviving ones, up to
    ``max_features``. ``ids`` (M,) int64 (increasing) and ``points`` (M, 2) float32 are the current tracks.

    Each track is searched from where its last displacement predicts it (new corners: the median
    displacement). Tracks followed at least once use only ``predict_levels`` pyramid levels from there: the
    coarse levels of a full pyramid mix surfaces at different depths and, on periodic texture (brick walls),
    lock onto the wrong period.
    """

    def __init__(self, max_features: int = 600, quality: float = 0.01, min_distance: int = 8, win_size: int = 21,
                 levels: int = 3, fb_threshold: float = 1.0, predict_levels: int = 1):  # fmt: skip
        self.max_features, self.quality, self.min_distance = max_features, quality, min_distance
        self.fb_threshold, self.levels, self.predict_levels = fb_threshold, levels, predict_levels
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01)
        self.lk = dict(winSize=(win_size, win_size), criteria=criteria)
        self.grey: np.ndarray | None = None
        self.ids = np.zeros(0, np.int64)
        self.points = np.zeros((0, 2), np.float32)
        self.velocity = np.zeros((0, 2), np.float32)  # last displacement of each track, the next prediction
        self.age = np.zeros(0, int)  # frames each track has been followed
        self._next_id = 0

    def _select(self, mask) -> None:
        arrays = (self.ids, self.points, self.velocity, self.age)
        self.ids, self.points, self.velocity, self.age = (a[mask] for a in arrays)

    def track(self, grey: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Follow the tracks into ``grey``: ``(ids (M,), previous pixels (M, 2), current pixels (M, 2))``."""
        prev, self.grey = self.grey, grey
        if prev is None or not len(self.points):
            self._select(slice(0, 0))
            return self.ids, self.points, self.points
        found, ok = self.points.copy(), np.zeros(len(self.points), bool)
        young = self.age == 0
        for sel, levels in ((young, self.levels), (~young, self.predict_levels)):
            if sel.any():
                start = self.points[sel].reshape(-1, 1, 2)
                guess = start + self.velocity[sel].reshape(-1, 1, 2)
                q, st, _ = cv2.calcOpticalFlowPyrLK(prev, grey, start, guess, maxLevel=levels,
                                                    flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **self.lk)  # fmt: skip
                found[sel], ok[sel] = q.reshape(-1, 2), st[:, 0] == 1
        back, st, _ = cv2.calcOpticalFlowPyrLK(grey, prev, found.reshape(-1, 1, 2), None, maxLevel=self.levels,
                                               **self.lk)  # fmt: skip
        H, W = grey.shape
        ok &= (st[:, 0] == 1) & (np.linalg.norm(back.reshape(-1, 2) - self.points, axis=1) < self.fb_threshold)
        ok &= (found[:, 0] >= 0) & (found[:, 0] <= W - 1) & (found[:, 1] >= 0) & (found[:, 1] <= H - 1)
        previous = self.points[ok]
        self._select(ok)
        self.points, self.velocity, self.age = found[ok], found[ok] - previous, self.age + 1
        return self.ids, previous, self.points

    def keep(self, mask: np.ndarray) -> None:
        """Keep only the current tracks where ``mask`` (M,) is true."""
        self._select(mask)

    def replenish(self) -> None:
        """Detect new corners in the current image, at least ``min_distance`` from the surviving tracks."""
        missing = self.max_features - len(self.points)
        if self.grey is None or missing <= 0:
            return
        mask = np.full(self.grey.shape, 255, np.uint8)
        for u, v in np.round(self.points).astype(int):
            cv2.circle(mask, (int(u), int(v)), self.min_distance, 0, -1)
        new = cv2.goodFeaturesToTrack(self.grey, missing, self.quality, self.min_distance, mask=mask)
        if new is None:
            return
        new = new.reshape(-1, 2).astype(np.float32)
        guess = np.median(self.velocity, 0) if len(self.velocity) else np.zeros(2)
        self.points = np.concatenate([self.points, new])
        self.velocity = np.concatenate([self.velocity, np.tile(guess, (len(new), 1))]).astype(np.float32)
        self.age = np.concatenate([self.age, np.zeros(len(new), int)])
        self.ids = np.concatenate([self.ids, np.arange(self._next_id, self._next_id + len(new))])
        self._next_id += len(new)
