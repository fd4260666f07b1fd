"""The on-line rig estimator's SIFT: keypoints land on the blobs' centres (known sub-pixel centres as the reference;
OpenCV's own quarter-pixel bias removed), on a shrunk copy of a wide image too; its matches are OpenCV's brute-force matcher's
mutual nearest neighbours that pass the ratio test."""

import cv2
import numpy as np
import pytest

from ocalib.rigba.features import SIFT_OFFSET, SiftExtractor, match_features

CENTRES = np.array([(200.3, 100.7), (512.6, 150.2), (803.1, 220.4)])


def _blobs(height: int = 300, width: int = 1000) -> np.ndarray:
    """Gaussian blobs (sigma 6 px) at ``CENTRES`` (integer pixel centres), uint8."""
    yy, xx = np.mgrid[0:height, 0:width].astype(float)
    image = sum(np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * 6.0**2)) for x, y in CENTRES)
    return (255 * image / image.max()).astype(np.uint8)


def _nearest(keypoints: np.ndarray) -> np.ndarray:
    """(3, 2) the keypoint nearest each blob centre."""
    return np.stack([keypoints[np.argmin(np.linalg.norm(keypoints - c, axis=1))] for c in CENTRES])


def test_opencv_places_keypoints_a_quarter_pixel_off_and_the_extractor_removes_it():
    raw = _nearest(np.array([k.pt for k in cv2.SIFT_create(64, contrastThreshold=0.01).detect(_blobs(), None)]))
    np.testing.assert_allclose(raw, CENTRES + SIFT_OFFSET, atol=0.06)
    np.testing.assert_allclose(_nearest(SiftExtractor(64)(_blobs()).keypoints), CENTRES, atol=0.06)


@pytest.mark.parametrize("max_width", [500, 250])
def test_keypoints_of_a_shrunk_copy_are_in_the_images_pixels(max_width):
    shrunk = _nearest(SiftExtractor(64, max_width=max_width)(_blobs()).keypoints)
    np.testing.assert_allclose(shrunk, CENTRES, atol=0.06 * 1000 / max_width)


def test_an_image_within_the_width_is_detected_as_it_is():
    image = _blobs()
    a, b = SiftExtractor(64)(image), SiftExtractor(64, max_width=1000)(image)
    np.testing.assert_array_equal(a.keypoints, b.keypoints)
    np.testing.assert_array_equal(a.descriptors, b.descriptors)


def _unit(x: np.ndarray) -> np.ndarray:
    return (x / np.linalg.norm(x, axis=1, keepdims=True)).astype(np.float32)


@pytest.mark.parametrize("ratio", [0.8, 0.6])
def test_matches_are_opencvs_mutual_nearest_neighbours_that_pass_the_ratio_test(ratio):
    rng = np.random.default_rng(3)
    a = _unit(rng.random((300, 128)))
    order = rng.permutation(300)[:250]
    b = _unit(np.concatenate([a[order] + rng.normal(0, 0.01 + 0.04 * rng.random((250, 1)), (250, 128)),
                              rng.random((80, 128))]))  # fmt: skip
    a = np.concatenate([a, _unit(a[order[:40]] + rng.normal(0, 0.03, (40, 128)))])  # near twins: not mutual
    ours = {tuple(m) for m in match_features(a, b, ratio)}
    matcher = cv2.BFMatcher(cv2.NORM_L2)
    nearest_two = matcher.knnMatch(a, b, k=2)
    back = {m.queryIdx: m.trainIdx for m in matcher.match(b, a)}
    reference = {(m.queryIdx, m.trainIdx) for m, n in nearest_two
                 if m.distance < ratio * n.distance and back[m.trainIdx] == m.queryIdx}  # fmt: skip
    assert 50 < len(reference) < 250  # some pass, some fail the ratio test
    assert ours == reference
