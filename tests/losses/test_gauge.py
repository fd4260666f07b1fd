"""The scale gauge: zero inside its band, the closed-form square outside, a gradient that pulls the scale back."""

import math

import pytest
import torch

from ocalib.losses.gauge import scale_gauge


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_scale_gauge_against_closed_form(dtype):
    torch.manual_seed(0)
    shape = torch.rand(2, 1, 8, 12, dtype=dtype).add(0.5)  # depth map shape, mean log ~0.03
    log_mean = shape.log().mean().item()
    for scale in (1.0, 10.0, 30.0, 200.0, 0.3):  # range [0.1, 1000]: centre 10, band [3.16, 31.6]
        depth = (shape * scale).requires_grad_()
        excess = abs(log_mean + math.log(scale) - math.log(10.0)) - 0.5 * math.log(10.0)
        value = scale_gauge(depth, 0.1, 1000.0)
        assert value.item() == pytest.approx(max(excess, 0.0) ** 2, rel=1e-5, abs=1e-12)
        value.backward()
        pull = (depth.grad * depth).sum().item()  # d value / d log(scale)
        if excess <= 0:
            assert pull == 0.0
        else:  # the gradient step moves the scale back towards the centre
            assert pull == pytest.approx(2 * excess * math.copysign(1.0, math.log(scale) - math.log(10.0)), rel=1e-4)


def test_scale_gauge_gradcheck():
    depth = torch.rand(1, 1, 4, 5, dtype=torch.float64).add(0.1).mul(100).requires_grad_()
    assert scale_gauge(depth, 0.1, 1000.0) > 0
    assert torch.autograd.gradcheck(lambda d: scale_gauge(d, 0.1, 1000.0), (depth,))
