"""The ego-motion model: a depth network and a pairwise pose network, in two sizes.

Convention: images (B, 3, H, W) in [0, 1]; ``pose(target, source)`` is ``T_target_source`` (B, 4, 4), the pose
of the source camera in the target camera's frame (``p_target = T p_source``); depth in network units
(scale-ambiguous, consistent across frames when trained with the geometry-consistency loss).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from ocalib.errors import InputError
from ocalib.models.depth import DepthNet, disp_to_depth
from ocalib.models.pose import PoseNet

MIN_DEPTH, MAX_DEPTH = 0.1, 100.0  # the network's scale is held in the middle of it (ocalib.losses.gauge)

# size -> (depth net kwargs, pose net kwargs). "small": 2 CPU cores; "large": ResNet-18 widths for GPUs.
SIZES = {
    "small": (
        dict(widths=(16, 24, 32, 64, 96), decoder=(8, 16, 24, 32, 64), blocks=1),
        dict(widths=(16, 32, 48, 64, 96), head=64, blocks=1),
    ),
    "large": (
        dict(widths=(64, 64, 128, 256, 512), decoder=(16, 32, 64, 128, 256), blocks=2),
        dict(widths=(64, 64, 128, 256, 512), head=256, blocks=2),
    ),
}


class EgoMotionModel(nn.Module):
    """``depth_net`` (:class:`DepthNet`) and ``pose_net`` (:class:`PoseNet`); ``height``/``width``: the training
    resolution (the networks accept any size, but work best at this one)."""

    def __init__(self, size: str = "small", height: int = 64, width: int = 208):
        super().__init__()
        if size not in SIZES:
            raise InputError(f"unknown model size {size!r} (sizes: {', '.join(SIZES)})")
        depth_kw, pose_kw = SIZES[size]
        self.size, self.height, self.width = size, int(height), int(width)
        self.depth_net = DepthNet(**depth_kw)
        self.pose_net = PoseNet(**pose_kw)

    def disparities(self, image: Tensor) -> list[Tensor]:
        """(B, 3, H, W) -> sigmoid disparities at 4 scales, (B, 1, H/2^s, W/2^s), finest first."""
        return self.depth_net(image)

    def depth(self, image: Tensor, flip: bool = False) -> Tensor:
        """(B, 3, H, W) in [0, 1] -> depth (B, 1, H, W), network units, from the full-resolution disparity.

        ``flip``: average the disparity with that of the mirrored image, mirrored back (test-time flipping, like
        monodepth2's post-processing without its edge ramps; the networks train with random flips). Twice the
        depth network's cost; measured on the eight held-out cameras: abs rel 0.001-0.007 lower on every one, the
        aligned motions no better (docs/results-egomotion.md).
        """
        if not flip:
            return disp_to_depth(self.depth_net(image)[0], MIN_DEPTH, MAX_DEPTH)
        disp = self.depth_net(torch.cat([image, image.flip(-1)]))[0]
        return disp_to_depth(0.5 * (disp[: len(image)] + disp[len(image) :].flip(-1)), MIN_DEPTH, MAX_DEPTH)

    def pose(self, target: Tensor, source: Tensor) -> Tensor:
        """(B, 3, H, W) each -> ``T_target_source`` (B, 4, 4) float32 (``p_target = T p_source``)."""
        return self.pose_net(target, source)
