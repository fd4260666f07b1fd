"""SSIM against an OpenCV box-filter reference, smoothness properties, minimum reprojection with auto-masking."""

import cv2
import numpy as np
import torch

from ocalib.losses import edge_aware_smoothness, min_reprojection, photometric_error, ssim_error


def reference_ssim_error(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(1 - SSIM) / 2 per pixel and channel, 3x3 box window (cv2.blur), for interior pixels (C, H-2, W-2)."""
    out = []
    for a, b in zip(x, y):
        mean = lambda m: cv2.blur(m, (3, 3))[1:-1, 1:-1]  # noqa: E731
        ma, mb = mean(a), mean(b)
        va, vb, cov = mean(a * a) - ma**2, mean(b * b) - mb**2, mean(a * b) - ma * mb
        ssim = (2 * ma * mb + 1e-4) * (2 * cov + 9e-4) / ((ma**2 + mb**2 + 1e-4) * (va + vb + 9e-4))
        out.append(np.clip((1 - ssim) / 2, 0, 1))
    return np.stack(out)


def test_ssim_matches_a_box_filter_reference():
    g = torch.Generator().manual_seed(0)
    x, y = torch.rand(2, 1, 3, 10, 14, generator=g, dtype=torch.float64)
    y = 0.5 * x + 0.5 * y  # correlated
    expected = reference_ssim_error(x[0].numpy(), y[0].numpy()).mean(0)
    got = ssim_error(x, y)[0, 0].numpy()
    np.testing.assert_allclose(got[1:-1, 1:-1], expected, atol=1e-10)
    np.testing.assert_array_equal(got[0, 1:-1], got[1, 1:-1])  # the border repeats its neighbour
    assert ssim_error(x, x).abs().max() < 1e-6


def test_ssim_in_float32_under_mixed_precision():
    """In bfloat16 the variances E[x^2] - E[x]^2 cancel; under autocast the error is the float32 one (against
    the OpenCV reference) and its gradient finite, on a nearly flat patch where bfloat16 alone breaks down."""
    g = torch.Generator().manual_seed(0)
    x = 0.5 + 1e-3 * torch.rand(1, 3, 10, 14, generator=g)
    y = (x + 1e-3 * torch.rand(1, 3, 10, 14, generator=g)).requires_grad_()
    with torch.autocast("cpu", dtype=torch.bfloat16):
        got = ssim_error(x, y)
    expected = reference_ssim_error(x[0].numpy(), y[0].detach().numpy()).mean(0)
    assert got.dtype == torch.float32
    np.testing.assert_allclose(got[0, 0, 1:-1, 1:-1].detach().numpy(), expected, atol=1e-4)
    got.sum().backward()
    assert torch.isfinite(y.grad).all()


def test_photometric_error_weights_ssim_and_l1():
    g = torch.Generator().manual_seed(1)
    x, y = torch.rand(2, 2, 3, 8, 9, generator=g)
    l1 = (x - y).abs().mean(1, keepdim=True)
    torch.testing.assert_close(photometric_error(x, y, alpha=0.0), l1)
    torch.testing.assert_close(photometric_error(x, y), 0.85 * ssim_error(x, y) + 0.15 * l1)
    assert photometric_error(x, x).abs().max() < 1e-6


def test_smoothness_is_zero_on_constant_and_scale_invariant():
    g = torch.Generator().manual_seed(2)
    image = torch.rand(2, 3, 8, 10, generator=g)
    assert edge_aware_smoothness(torch.full((2, 1, 8, 10), 0.3), image) == 0
    disp = torch.rand(2, 1, 8, 10, generator=g) + 0.1
    torch.testing.assert_close(edge_aware_smoothness(5 * disp, image), edge_aware_smoothness(disp, image))
    # edges in the image damp the penalty on disparity edges
    flat, edgy = torch.zeros(1, 3, 8, 10), torch.zeros(1, 3, 8, 10)
    edgy[..., 5:] = 1
    step = torch.ones(1, 1, 8, 10)
    step[..., 5:] = 2
    assert edge_aware_smoothness(step, edgy) < 0.5 * edge_aware_smoothness(step, flat)


def test_min_reprojection_and_auto_mask():
    reprojection = torch.tensor([[[[0.2, 0.5, 1e3]], [[0.3, 1e3, 1e3]]]])  # (1, 2 sources, 1, 3 pixels)
    identity = torch.tensor([[[[0.1, 0.6, 0.8]], [[0.4, 0.7, 0.9]]]])
    error, used = min_reprojection(reprojection, identity)
    torch.testing.assert_close(error, torch.tensor([[[[0.1, 0.5, 0.8]]]]))
    torch.testing.assert_close(used, torch.tensor([[[[0.0, 1.0, 0.0]]]]))  # pixel 0: an unwarped source matches better
    error, used = min_reprojection(reprojection, identity, automask=False)
    torch.testing.assert_close(error, torch.tensor([[[[0.2, 0.5, 0.8]]]]))  # pixel 2 is outside every source
    torch.testing.assert_close(used, torch.tensor([[[[1.0, 1.0, 0.0]]]]))


def test_min_reprojection_cannot_gain_by_dropping_pixels():
    """Making a pixel's reprojection worse never lowers the loss (every pixel counts in the mean)."""
    identity = torch.tensor([[[[0.3, 0.3]]]])
    good = min_reprojection(torch.tensor([[[[0.1, 0.2]]]]), identity)[0].mean()
    worse = min_reprojection(torch.tensor([[[[0.1, 0.9]]]]), identity)[0].mean()
    assert worse > good
