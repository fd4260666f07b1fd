"""The radial residual test against a closed form: residuals made by a known radial distortion are found with its
size at the corner; noise alone is not."""

import numpy as np
import pytest

from ocalib.rigba.lens_check import MAX_CORNER_PX, radial_residual

FOCAL = np.array([300.0, 310.0])
CORNER = np.array([208.0, 64.0]) / FOCAL


def _projections(n: int, rng) -> np.ndarray:
    return rng.uniform(-1, 1, (n, 2)) * CORNER


@pytest.mark.parametrize("k1, k2", [(0.02, 0.0), (-0.03, 0.01), (0.0, 0.05), (0.003, 0.0)])
def test_a_radial_distortion_is_found_with_its_size(k1, k2):
    rng = np.random.default_rng(0)
    xy = _projections(2000, rng)
    r2 = (xy**2).sum(1, keepdims=True)
    residuals = (k1 * r2 + k2 * r2**2) * xy * FOCAL + rng.normal(0, 0.3, xy.shape)
    out = radial_residual(residuals, xy, FOCAL, CORNER)
    rc2 = CORNER @ CORNER
    expected = (k1 * rc2 + k2 * rc2**2) * np.linalg.norm(CORNER * FOCAL)  # the distortion's displacement there
    assert out.corner_px == pytest.approx(expected, abs=0.1)
    assert out.significant is bool(abs(expected) > MAX_CORNER_PX + 0.1)  # a bool (the JSON takes no numpy bool)


def test_noise_alone_is_not_a_lens():
    rng = np.random.default_rng(1)
    for _ in range(20):
        xy = _projections(3000, rng)
        out = radial_residual(rng.normal(0, 0.5, xy.shape), xy, FOCAL, CORNER)
        assert not out.significant and abs(out.corner_px) < 0.2


def test_too_few_observations_say_nothing():
    xy = np.zeros((3, 2))
    assert not radial_residual(xy, xy, FOCAL, CORNER).significant
