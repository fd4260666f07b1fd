"""Pictures for TensorBoard: colour-mapped disparity, masks and a top-view trajectory plot.

Convention: images (B, C, H, W) in [0, 1]; poses camera-to-first-frame (N, 4, 4), x right, z forward.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor


def colorize(disp: Tensor, cmap: str = "magma") -> Tensor:
    """Disparity (B, 1, H, W) -> RGB (B, 3, H, W), each image normalised to its 95th percentile."""
    from matplotlib import colormaps

    d = disp.detach().float().cpu()
    top = d.flatten(1).quantile(0.95, dim=1).clamp(min=1e-6)[:, None, None, None]
    rgb = colormaps[cmap]((d / top).clamp(0, 1)[:, 0].numpy())[..., :3]
    return torch.from_numpy(rgb).permute(0, 3, 1, 2).float()


def trajectory_figure(pred: np.ndarray, gt: np.ndarray | None, title: str = ""):
    """Top view (x, z) of a predicted trajectory (N, 4, 4), scaled to the ground truth's length when given."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4, 4))
    p = pred[:, :3, 3]
    if gt is not None:
        g = gt[:, :3, 3]
        steps = lambda x: np.linalg.norm(np.diff(x, axis=0), axis=1).sum()  # noqa: E731
        p = p * (steps(g) / max(steps(p), 1e-9))
        ax.plot(g[:, 0], g[:, 2], "k-", label="ground truth")
    ax.plot(p[:, 0], p[:, 2], "r-", label="predicted" + (" (scaled to its length)" if gt is not None else ""))
    ax.set_xlabel("x")
    ax.set_ylabel("z")
    ax.axis("equal")
    ax.legend(fontsize=7)
    ax.set_title(title, fontsize=8)
    fig.tight_layout()
    return fig
