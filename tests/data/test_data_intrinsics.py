"""K follows every resize, crop and flip: a known 3D point lands where the updated K projects it."""

import numpy as np
import pytest
import torch

from ocalib.data.intrinsics import flip_intrinsics, intrinsics_from_projection, scale_intrinsics
from ocalib.data.transforms import crop, hflip, resize

H, W = 48, 160
K = torch.tensor([[60.0, 0, 81.3], [0, 58.0, 22.7], [0, 0, 1]], dtype=torch.float64)
POINT = torch.tensor([0.4, -0.1, 2.0], dtype=torch.float64)


def project(K, X):
    x = K @ X
    return x[:2] / x[2]


def blob(uv, size=(H, W), sigma=2.0):
    """An image (1, 3, H, W) of a Gaussian blob centred at pixel position uv (integer pixel centres)."""
    v, u = torch.meshgrid(
        torch.arange(size[0], dtype=torch.float64), torch.arange(size[1], dtype=torch.float64), indexing="ij"
    )
    g = torch.exp(-((u - uv[0]) ** 2 + (v - uv[1]) ** 2) / (2 * sigma**2))
    return g.expand(1, 3, *size).float()


def centroid(image):
    g = image[0, 0].double()
    v, u = torch.meshgrid(
        torch.arange(g.shape[0], dtype=torch.float64), torch.arange(g.shape[1], dtype=torch.float64), indexing="ij"
    )
    return torch.stack([(g * u).sum(), (g * v).sum()]) / g.sum()


def sample():
    return {"image": blob(project(K, POINT)), "K": K.float()}


def test_blob_centroid_is_its_projection():
    np.testing.assert_allclose(centroid(sample()["image"]), project(K, POINT), atol=1e-3)


@pytest.mark.parametrize("size", [(24, 80), (36, 96), (64, 200)])
def test_resize(size):
    out = resize(sample(), size)
    assert out["image"].shape[-2:] == size
    np.testing.assert_allclose(centroid(out["image"]), project(out["K"].double(), POINT), atol=0.03)


def test_crop():
    out = crop(sample(), x0=37, y0=5, height=30, width=90)
    assert out["image"].shape[-2:] == (30, 90)
    np.testing.assert_allclose(centroid(out["image"]), project(out["K"].double(), POINT), atol=1e-3)


def test_flip():
    out = hflip(sample())
    np.testing.assert_allclose(
        centroid(out["image"]), project(out["K"].double(), POINT * torch.tensor([-1, 1, 1])), atol=1e-3
    )
    np.testing.assert_allclose(flip_intrinsics(flip_intrinsics(K, W), W), K)


def test_crop_then_resize_then_flip():
    out = hflip(resize(crop(sample(), 20, 4, 40, 120), (24, 80)))
    mirrored = POINT * torch.tensor([-1, 1, 1])
    np.testing.assert_allclose(centroid(out["image"]), project(out["K"].double(), mirrored), atol=0.03)


def test_batched_scales():
    Ks = K.expand(3, 3, 3)
    out = scale_intrinsics(Ks, torch.tensor([0.5, 1.0, 2.0], dtype=K.dtype), 0.5)
    for i, s in enumerate([0.5, 1.0, 2.0]):
        np.testing.assert_allclose(out[i, 0], [K[0, 0] * s, 0, (K[0, 2] + 0.5) * s - 0.5])
        np.testing.assert_allclose(out[i, 1], [0, K[1, 1] * 0.5, (K[1, 2] + 0.5) * 0.5 - 0.5])


def test_kitti_projection_matrix():
    """KITTI odometry seq 00, P1: camera 1 sits 0.54 m to the right of camera 0."""
    P1 = np.array([[718.856, 0, 607.1928, -386.1448], [0, 718.856, 185.2157, 0], [0, 0, 1, 0]])
    K1, T = intrinsics_from_projection(P1)
    np.testing.assert_allclose(K1, P1[:, :3])
    np.testing.assert_allclose(T[:3, 3], [0.5372, 0, 0], atol=1e-4)


@pytest.mark.parametrize("out_size", [(24, 80), (36, 120), (64, 200)])
def test_resize_when_reading(tmp_path, out_size):
    """cv2 resizing at read time (area / bilinear) keeps pixel centres as resize_intrinsics says."""
    import cv2

    from ocalib.data.image_io import read_image
    from ocalib.data.intrinsics import resize_intrinsics

    path = tmp_path / "blob.png"
    cv2.imwrite(str(path), np.round(255 * sample()["image"][0].permute(1, 2, 0).numpy()).astype(np.uint8))
    image = read_image(path, (H, W), out_size)
    assert image.shape == (3, *out_size)
    K_new = resize_intrinsics(K, (H, W), out_size)
    np.testing.assert_allclose(centroid(image[None]), project(K_new, POINT), atol=0.05)


def test_hue_rotation_keeps_grey_and_luma():
    from ocalib.data.augment import rotate_hue

    grey = torch.full((3, 4, 4), 0.4)
    torch.testing.assert_close(rotate_hue(grey, 1.0), grey)
    colour = torch.rand(3, 4, 4)
    luma = torch.tensor([0.299, 0.587, 0.114])
    torch.testing.assert_close(
        torch.einsum("c,chw->hw", luma, rotate_hue(colour, 0.7)), torch.einsum("c,chw->hw", luma, colour)
    )
    assert not torch.allclose(rotate_hue(colour, 0.7), colour)
