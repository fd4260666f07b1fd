"""Keypoints and matches of one camera's images for the on-line rig estimator: OpenCV's SIFT with RootSIFT
descriptors, matched by mutual nearest neighbours and Lowe's ratio test.

OpenCV's SIFT rather than COLMAP's here because a stream pays it every keyframe: at 128x416 it extracts a
similar number of keypoints in about a quarter of the time (``python bench/bench_rig_online.py`` prints both).

Convention: keypoints in ocalib's pixels (integer pixel centres, as OpenCV's); converted to COLMAP's (+0.5) only
where they enter a reconstruction (:mod:`ocalib.rigba.window`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

# px: where OpenCV's SIFT places a blob's keypoint from its centre, along x and y, at every octave (its first octave
# doubles the image with centre-aligned interpolation, then reads coordinates as corner-aligned; opencv/opencv#23123)
SIFT_OFFSET = 0.25


@dataclass(frozen=True)
class Features:
    """One image's ``keypoints`` (N, 2) float64 pixels and ``descriptors`` (N, 128) float32, unit length."""

    keypoints: np.ndarray
    descriptors: np.ndarray

    def __len__(self) -> int:
        return len(self.keypoints)


class SiftExtractor:
    """SIFT keypoints of a grayscale image (H, W) uint8, at most ``max_features``, with RootSIFT descriptors
    (the square root of the L1-normalised SIFT descriptor: Euclidean distance then compares as Hellinger's). An
    image wider than ``max_width`` is detected on a copy shrunk to that width (area-averaged; its cost grows with the
    pixels) and its keypoints scaled back to the image's pixels."""

    def __init__(self, max_features: int = 1024, contrast_threshold: float = 0.01, max_width: int | None = None):
        self._sift = cv2.SIFT_create(nfeatures=max_features, contrastThreshold=contrast_threshold)
        self.max_width = max_width

    def __call__(self, image: np.ndarray) -> Features:
        height, width = image.shape[:2]
        if self.max_width and width > self.max_width:
            image = cv2.resize(image, (self.max_width, max(round(height * self.max_width / width), 1)),
                               interpolation=cv2.INTER_AREA)  # fmt: skip
        keypoints, descriptors = self._sift.detectAndCompute(image, None)
        if descriptors is None or not keypoints:
            return Features(np.zeros((0, 2)), np.zeros((0, 128), np.float32))
        descriptors = np.sqrt(descriptors / np.maximum(descriptors.sum(1, keepdims=True), 1e-12))
        scale = np.array([width / image.shape[1], height / image.shape[0]])
        xy = np.array([k.pt for k in keypoints], dtype=np.float64)
        # integer pixel centres: pixel j of the copy averages the image's j s .. (j + 1) s - 1; OpenCV's quarter
        # pixel removed first (a bias every camera shares in its own axes: 0.1-0.2 deg of relative rotation at 128x416)
        xy = (xy - SIFT_OFFSET + 0.5) * scale - 0.5
        return Features(xy, descriptors.astype(np.float32))


def match_features(a: np.ndarray, b: np.ndarray, ratio: float = 0.8) -> np.ndarray:
    """Matches (M, 2) of index pairs (i in ``a``, j in ``b``) between unit descriptors ``a`` (N, D) and ``b``
    (N', D): each other's nearest neighbour, and the nearest clearly nearer than the second (distance ratio below
    ``ratio``)."""
    if len(a) < 2 or len(b) < 2:
        return np.zeros((0, 2), np.int64)
    similarity = a @ b.T  # for unit vectors, squared distance = 2 - 2 similarity
    rows = np.arange(len(a))
    best = np.argmax(similarity, 1)
    nearest = similarity[rows, best]
    mutual = nearest >= similarity.max(0)[best]  # a column's maximum, not its argmax: that one reads strided
    similarity[rows, best] = -np.inf
    second = similarity.max(1)
    distinct = np.maximum(2 - 2 * nearest, 0) < ratio**2 * np.maximum(2 - 2 * second, 0)
    keep = np.flatnonzero(distinct & mutual)
    return np.stack([keep, best[keep]], 1)
