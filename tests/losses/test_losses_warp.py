"""Inverse warp: identity, a known motion against cv2.projectPoints, validity mask, float64 gradcheck."""

import cv2
import numpy as np
import pytest
import torch

from ocalib.geometry.pose import make_pose
from ocalib.losses import inverse_warp
from ocalib.models import motion_to_pose

H, W = 12, 20


def intrinsics(B=1, dtype=torch.float32, device="cpu"):
    K = torch.tensor(
        [[14.0, 0, (W - 1) / 2 + 0.3], [0, 13.0, (H - 1) / 2 - 0.2], [0, 0, 1]], dtype=dtype, device=device
    )
    return K.expand(B, 3, 3).clone()


def coordinate_image(B=1, dtype=torch.float32, device="cpu"):
    """An image whose channels are the pixel's own (u, v): bilinear sampling returns the sampled position."""
    v, u = torch.meshgrid(
        torch.arange(H, dtype=dtype, device=device), torch.arange(W, dtype=dtype, device=device), indexing="ij"
    )
    return torch.stack([u, v]).expand(B, 2, H, W).clone()


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_identity_warp_returns_the_image(device, dtype):
    g = torch.Generator().manual_seed(0)
    source = torch.rand(2, 3, H, W, generator=g, dtype=dtype).to(device)
    depth = (1 + 10 * torch.rand(2, 1, H, W, generator=g, dtype=dtype)).to(device)
    T = torch.eye(4, dtype=dtype, device=device).expand(2, 4, 4)
    warp = inverse_warp(source, depth, T, intrinsics(2, dtype, device), source_depth=depth)
    torch.testing.assert_close(warp.image, source, atol=1e-5, rtol=0)
    torch.testing.assert_close(warp.depth, depth)
    torch.testing.assert_close(warp.source_depth, depth, atol=1e-4, rtol=1e-5)
    assert warp.mask[..., 1:-1, 1:-1].all()


def test_known_motion_agrees_with_cv2_project_points():
    g = torch.Generator().manual_seed(1)
    depth = 2 + 3 * torch.rand(1, 1, H, W, generator=g, dtype=torch.float64)
    motion = torch.tensor([[0.02, -0.05, 0.01, 0.3, -0.1, 0.4]], dtype=torch.float64)
    T = motion_to_pose(motion)  # p_source = T p_target
    K = intrinsics(1, torch.float64)
    warp = inverse_warp(coordinate_image(1, torch.float64), depth, T, K)

    v, u = np.mgrid[:H, :W].astype(np.float64)
    Kn = K[0].numpy()
    z = depth[0, 0].numpy()
    points = np.stack([(u - Kn[0, 2]) / Kn[0, 0] * z, (v - Kn[1, 2]) / Kn[1, 1] * z, z], -1).reshape(-1, 3)
    rvec, _ = cv2.Rodrigues(T[0, :3, :3].numpy())
    pixels, _ = cv2.projectPoints(points, rvec, T[0, :3, 3].numpy(), Kn, None)
    pixels = pixels.reshape(H, W, 2)
    inside = (pixels[..., 0] >= 0) & (pixels[..., 0] <= W - 1) & (pixels[..., 1] >= 0) & (pixels[..., 1] <= H - 1)
    assert inside.mean() > 0.5
    np.testing.assert_array_equal(warp.mask[0, 0].numpy() > 0, inside)
    np.testing.assert_allclose(warp.image[0, 0].numpy()[inside], pixels[..., 0][inside], atol=1e-9)
    np.testing.assert_allclose(warp.image[0, 1].numpy()[inside], pixels[..., 1][inside], atol=1e-9)
    z_source = points @ T[0, :3, :3].numpy().T + T[0, :3, 3].numpy()
    np.testing.assert_allclose(warp.depth[0, 0].numpy(), z_source[:, 2].reshape(H, W), atol=1e-12)


def test_points_behind_the_source_camera_are_invalid():
    depth = torch.full((1, 1, H, W), 2.0)
    T = make_pose(torch.eye(3)[None], torch.tensor([[0.0, 0.0, -3.0]]))  # the source camera is 3 m in front
    warp = inverse_warp(torch.rand(1, 3, H, W), depth, T, intrinsics())
    assert (warp.depth < 0).all() and not warp.mask.any()


def test_warp_gradcheck_float64():
    g = torch.Generator().manual_seed(2)
    h, w = 5, 6
    K = torch.tensor([[[6.0, 0, 2.7], [0, 6.0, 2.1], [0, 0, 1]]], dtype=torch.float64)
    source = torch.rand(1, 2, h, w, generator=g, dtype=torch.float64, requires_grad=True)
    source_depth = (1 + torch.rand(1, 1, h, w, generator=g, dtype=torch.float64)).requires_grad_()
    depth = (2 + torch.rand(1, 1, h, w, generator=g, dtype=torch.float64)).requires_grad_()
    motion = torch.tensor([[0.01, 0.02, -0.01, 0.05, 0.02, 0.1]], dtype=torch.float64, requires_grad=True)

    def f(source, depth, motion, source_depth):
        warp = inverse_warp(source, depth, motion_to_pose(motion), K, source_depth, padding_mode="border")
        return warp.image, warp.depth, warp.source_depth

    assert torch.autograd.gradcheck(f, (source, depth, motion, source_depth), eps=1e-6, atol=1e-5)
