"""The frame-to-frame scale offset against closed forms: a known scale, outliers beyond the band, gradients."""

import math

import pytest
import torch

from ocalib.losses import log_scale_offset


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_offset_is_the_log_scale_and_ignores_occlusions(dtype):
    g = torch.Generator().manual_seed(0)
    source = 1 + 9 * torch.rand(2, 1, 12, 16, generator=g, dtype=dtype)
    scale = torch.tensor([1.3, 0.9], dtype=dtype).view(2, 1, 1, 1)
    projected = source * scale * (1 + 0.01 * torch.randn(2, 1, 12, 16, generator=g, dtype=dtype))
    occluded = torch.rand(2, 1, 12, 16, generator=g) < 0.2  # a fifth of the pixels see another surface
    projected = torch.where(occluded, projected * 3, projected)
    mask = torch.ones_like(source)
    mask[:, :, :, :3] = 0  # outside the source image
    projected[:, :, :, :3] = 100.0  # whatever lies there must not count
    offset = log_scale_offset(projected, source, mask)
    assert offset.dtype == dtype
    torch.testing.assert_close(offset, scale.log().flatten(), atol=3e-3, rtol=0)
    plain = (projected / source).log()[mask.bool().expand_as(projected)].view(2, -1).mean(1)
    assert (plain - scale.log().flatten()).abs().min() > 0.1  # the plain mean would be far off


def test_offset_with_no_valid_pixel_is_zero():
    depth = torch.ones(1, 1, 4, 4)
    assert log_scale_offset(2 * depth, depth, torch.zeros_like(depth)).item() == 0.0


def test_offset_gradcheck():
    g = torch.Generator().manual_seed(1)
    source = 1 + torch.rand(1, 1, 5, 6, generator=g, dtype=torch.float64)
    projected = (source * 1.02 * (1 + 0.01 * torch.rand(1, 1, 5, 6, generator=g, dtype=torch.float64))).requires_grad_()
    mask = torch.ones_like(source)
    assert torch.autograd.gradcheck(lambda p: log_scale_offset(p, source, mask), (projected,))
    log_scale_offset(projected, source, mask).sum().backward()
    assert math.isclose(projected.grad.mul(projected).sum().item(), 1.0, rel_tol=1e-9)  # d offset / d log scale = 1
