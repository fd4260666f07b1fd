"""Camera imperfections, applied only when asked (``--photometric``): per-camera gain, per-frame
exposure jitter, radial vignetting and Gaussian read noise. Deterministic from the seed.

Images (3, H, W) in [0, 1]; the result is clipped to [0, 1].
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor


class Photometric:
    """Draws each camera's gain (0.75-1.25), vignetting strength (0.2-0.45 at the corners) and noise
    level (sigma 0.005-0.015) from ``seed``; ``apply`` adds a per-frame exposure jitter (2% rms)."""

    def __init__(self, seed: int, num_cameras: int):
        rng = np.random.default_rng([seed, 99])
        self.seed = seed
        self.gain = rng.uniform(0.75, 1.25, num_cameras)
        self.vignette = rng.uniform(0.2, 0.45, num_cameras)
        self.sigma = rng.uniform(0.005, 0.015, num_cameras)

    def apply(self, image: Tensor, camera: int, frame: int) -> Tensor:
        _, H, W = image.shape
        g = torch.Generator().manual_seed(int(self.seed) * 1_000_003 + camera * 100_003 + frame)
        exposure = float(torch.exp(0.02 * torch.randn((), generator=g)))
        y = torch.linspace(-1, 1, H, device=image.device)[:, None]
        x = torch.linspace(-1, 1, W, device=image.device)[None]
        falloff = 1 - self.vignette[camera] * (x**2 + y**2) / 2
        noise = torch.randn(image.shape, generator=g).to(image.device) * self.sigma[camera]
        return (image * (self.gain[camera] * exposure) * falloff + noise).clamp(0, 1)
