"""Pairwise pose network: two frames in, one 6-DoF motion out.

Convention: ``forward(target, source)`` returns ``T_target_source`` (B, 4, 4), the pose of the source camera
in the target camera's frame (``p_target = R p_source + t``), from an axis-angle rotation and a translation.
Training starts near the identity: the last layer's initial weights are scaled by 0.01 (monodepth2 scales the
output by 0.01 instead; under Adam that also makes the motion learn 100x slower, and depth then collapses to its
minimum to explain the image motion: measured, the sigmoid disparity saturated within 80 steps).
"""

from __future__ import annotations

import torch
from kornia.geometry.conversions import axis_angle_to_rotation_matrix
from torch import Tensor, nn

from ocalib.geometry.pose import make_pose
from ocalib.models.depth import MEAN, STD
from ocalib.models.layers import Encoder


def motion_to_pose(motion: Tensor) -> Tensor:
    """(B, 6) axis-angle (radians) and translation -> (B, 4, 4) pose."""
    return make_pose(axis_angle_to_rotation_matrix(motion[:, :3]), motion[:, 3:])


class PoseNet(nn.Module):
    """Encoder on the stacked pair (6 channels) + a small convolutional head averaged to 6 numbers."""

    def __init__(
        self, widths=(16, 32, 48, 64, 96), head: int = 64, blocks: int = 1, scale: float = 1.0, init_gain: float = 0.01
    ):
        super().__init__()
        self.encoder = Encoder(6, widths, blocks)
        self.head = nn.Sequential(
            nn.Conv2d(widths[-1], head, 1),
            nn.ReLU(inplace=True),
            nn.Conv2d(head, head, 3, padding=1),
            nn.ReLU(inplace=True),
            nn.Conv2d(head, 6, 1),
        )
        with torch.no_grad():  # small output initialisation: x init_gain (0.01) of a default-initialised head
            self.head[-1].weight.mul_(init_gain)
            self.head[-1].bias.zero_()
        self.scale = scale

    def motion(self, target: Tensor, source: Tensor) -> Tensor:
        """(B, 3, H, W) pair -> (B, 6): axis-angle and translation of ``T_target_source``.

        Antisymmetric: ``(f(target, source) - f(source, target)) / 2``, so swapping the frames negates the motion
        (the inverse, to first order) and identical frames give exactly the identity.
        """
        B = len(target)
        x = (torch.cat([torch.cat([target, source], 1), torch.cat([source, target], 1)]) - MEAN) / STD
        m = self.head(self.encoder(x)[-1]).mean((-2, -1))
        return self.scale * 0.5 * (m[:B] - m[B:])

    def forward(self, target: Tensor, source: Tensor) -> Tensor:
        return motion_to_pose(self.motion(target, source))
