"""Sparse KLT feature tracks with persistent ids: Shi-Tomasi corners followed by pyramidal Lucas-Kanade,
a forward-backward check, and new corners where the tracks thin out.

Convention: pixel coordinates (u, v) with integer pixel centres (OpenCV's and kornia's), float32.
"""

from __future__ import annotations

import cv2
import numpy as np


class KLTTracker:
    """Tracks corners from frame to frame on 8-bit grey images (H, W).

    ``track(grey)`` returns the tracks seen in both the previous and this frame; ``keep(mask)`` drops
    tracks (e.g. outliers of the two-view geometry); ``replenish()`` adds corners away from the surviving
    ones, up to ``max_features``. ``ids`` (M,) int64 and ``points`` (M, 2) float32 are the current tracks.
    """

    def __init__(self, max_features: int = 600, quality: float = 0.01, min_distance: int = 8, win_size: int = 21,
                 levels: int = 3, fb_threshold: float = 1.0, predict_levels: int | None = 1):  # fmt: skip
        self.max_features, self.quality, self.min_distance = max_features, quality, min_distance
        self.fb_threshold = fb_threshold
        self.lk = dict(winSize=(win_size, win_size), maxLevel=levels,
                       criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01))  # fmt: skip
        self.predict_levels = predict_levels
        self.grey: np.ndarray | None = None
        self.ids = np.zeros(0, np.int64)
        self.points = np.zeros((0, 2), np.float32)
        self.velocity = np.zeros((0, 2), np.float32)  # last displacement of each track, the next guess
        self.age = np.zeros(0, int)  # frames each track has been followed
        self._next_id = 0

    def track(self, grey: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Follow the tracks into ``grey``: ``(ids (M,), previous pixels (M, 2), current pixels (M, 2))``."""
        prev, self.grey = self.grey, grey
        if prev is None or not len(self.points):
            self.ids, self.points, self.velocity, self.age = self.ids[:0], self.points[:0], self.velocity[:0], self.age[:0]
            return self.ids, self.points, self.points
        p1, st1 = self.points.copy(), np.zeros(len(self.points), bool)
        young = self.age == 0 if self.predict_levels is not None else np.ones(len(p1), bool)
        for sel, levels in ((young, self.lk["maxLevel"]), (~young, self.predict_levels)):
            if sel.any():  # from where the last displacement predicts the point
                guess = (self.points[sel] + self.velocity[sel]).reshape(-1, 1, 2)
                q, st, _ = cv2.calcOpticalFlowPyrLK(prev, grey, self.points[sel].reshape(-1, 1, 2), guess,
                                                   flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **dict(self.lk, maxLevel=levels))  # fmt: skip
                p1[sel], st1[sel] = q.reshape(-1, 2), st[:, 0] == 1
        back, st2, _ = cv2.calcOpticalFlowPyrLK(grey, prev, p1.reshape(-1, 1, 2), None, **self.lk)
        H, W = grey.shape
        back = back.reshape(-1, 2)
        ok = st1 & (st2[:, 0] == 1) & (np.linalg.norm(back - self.points, axis=1) < self.fb_threshold)
        ok &= (p1[:, 0] >= 0) & (p1[:, 0] <= W - 1) & (p1[:, 1] >= 0) & (p1[:, 1] <= H - 1)
        previous = self.points[ok]
        self.ids, self.points, self.velocity = self.ids[ok], p1[ok], p1[ok] - previous
        self.age = self.age[ok] + 1
        return self.ids, previous, self.points

    def keep(self, mask: np.ndarray) -> None:
        """Keep only the current tracks where ``mask`` (M,) is true."""
        self.ids, self.points, self.velocity, self.age = self.ids[mask], self.points[mask], self.velocity[mask], self.age[mask]

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
        guess = np.median(self.velocity, 0) if len(self.velocity) else np.zeros(2, np.float32)
        self.points = np.concatenate([self.points, new])
        self.velocity = np.concatenate([self.velocity, np.broadcast_to(guess, new.shape)]).astype(np.float32)
        self.age = np.concatenate([self.age, np.zeros(len(new), int)])
        self.ids = np.concatenate([self.ids, np.arange(self._next_id, self._next_id + len(new))])
        self._next_id += len(new)

