"""Renders of single-camera pose sequences in the synthetic street world, for the front-end tests."""

import numpy as np
import torch

from ocalib.synth import WorldTensors, make_world, render_view


def render_poses(poses: np.ndarray, K: np.ndarray, seed: int = 3, height: int = 128, width: int = 416) -> np.ndarray:
    """Render camera-to-world poses (N, 4, 4) of one camera in the street world of ``seed``:
    images (N, H, W, 3) uint8."""
    xy = poses[:, :2, 3]
    world = WorldTensors.from_world(make_world(seed, xy.min(0) - 60, xy.max(0) + 60))
    out = []
    with torch.inference_mode():
        for pose in poses:
            image, _ = render_view(world, K, pose, height, width, 2)
            out.append((image.permute(1, 2, 0).numpy() * 255 + 0.5).clip(0, 255).astype(np.uint8))
    return np.stack(out)
