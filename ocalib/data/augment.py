"""Snippet augmentation: one random draw per snippet, applied identically to all of its frames.

Colour jitter (kornia: brightness shift, contrast and saturation factors; a hue rotation in YIQ space, a 3x3
matrix ~10x cheaper than kornia's HSV round trip), a horizontal flip
and a random crop resized back to the input size; K, depth and poses follow (see :mod:`ocalib.data.transforms`).

Convention: images (S, 3, H, W) in [0, 1]; draws come from torch's global RNG, which the ``DataLoader``
seeds per worker from its generator (or ``lightning.seed_everything`` without workers).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import kornia.enhance as ke
import torch

from ocalib.data.transforms import crop, hflip, resize

_RGB_TO_YIQ = torch.tensor([[0.299, 0.587, 0.114], [0.596, -0.274, -0.322], [0.211, -0.523, 0.312]])


def rotate_hue(image: torch.Tensor, angle: float) -> torch.Tensor:
    """Rotate the chroma of RGB images (..., 3, H, W) by ``angle`` radians about the luma axis (YIQ)."""
    c, s = math.cos(angle), math.sin(angle)
    rotation = torch.tensor([[1.0, 0, 0], [0, c, -s], [0, s, c]])
    M = (torch.linalg.inv(_RGB_TO_YIQ) @ rotation @ _RGB_TO_YIQ).to(image)
    return torch.einsum("ij,...jhw->...ihw", M, image)


def _uniform(low: float, high: float) -> float:
    return low + (high - low) * torch.rand(()).item()


@dataclass
class SnippetAugmentation:
    """Random photometric and geometric augmentation of a snippet sample; zeros disable a part.

    ``brightness``: additive shift in [-b, b]; ``contrast``, ``saturation``: factors in [1 - c, 1 + c];
    ``hue``: rotation in [-h, h] turns; ``flip_p``: probability of a horizontal flip; ``max_zoom``: the crop
    is 1/z of the image in each direction, z uniform in [1, max_zoom], resized back to the input size.
    Measured (docs/results-egomotion.md): without the zoom the hand-held rigs' held-out depth was worse
    and its scale wandered more from frame to frame; 1.3 was not better than 1.15.
    """

    brightness: float = 0.2
    contrast: float = 0.2
    saturation: float = 0.2
    hue: float = 0.03
    flip_p: float = 0.5
    max_zoom: float = 1.15

    def __call__(self, sample: dict) -> dict:
        image = sample["image"]
        image = ke.adjust_brightness(image, _uniform(-self.brightness, self.brightness))
        image = ke.adjust_contrast(image, _uniform(1 - self.contrast, 1 + self.contrast))
        image = ke.adjust_saturation_with_gray_subtraction(image, _uniform(1 - self.saturation, 1 + self.saturation))
        image = rotate_hue(image, 2 * math.pi * _uniform(-self.hue, self.hue)).clamp(0, 1)
        sample = {**sample, "image": image}
        if torch.rand(()).item() < self.flip_p:
            sample = hflip(sample)
        H, W = image.shape[-2:]
        zoom = _uniform(1.0, self.max_zoom)
        h, w = round(H / zoom), round(W / zoom)
        if (h, w) != (H, W):
            y0, x0 = (torch.randint(0, n + 1, ()).item() for n in (H - h, W - w))
            sample = resize(crop(sample, x0, y0, h, w), (H, W))
        return sample
