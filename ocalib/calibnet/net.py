"""The on-line calibration net: a front end and the calibration head on one graph.

Each call takes one synchronised frame of every camera of B rigs; the front end (:mod:`ocalib.frontend`) turns it
into every camera's motion, the motions are chained into each camera's trajectory, and the head
(:class:`~ocalib.calib.drivers.online.OnlineCalibrator`) updates the rig's extrinsics. With the network front end
everything stays on one device and nothing is read back to the host inside a frame. The head's rotation goes back to the
front end with the next frame (the network's rig-held alignment uses it).

Convention: a camera's trajectory is ``T_first_cur = T_first_prev T_prev_cur`` (camera-to-first-frame, in the
front end's units). The head returns ``T_cam0_camk`` (``p_cam0 = R p_camk + t``) in camera 0's front-end units and
the scale that maps camera k's front-end units into camera 0's.
"""

from __future__ import annotations

import torch
from torch import nn

from ocalib.calib.drivers.online import OnlineCalibrator
from ocalib.calib.drivers.result import Calibration
from ocalib.frontend.base import FrontEnd


class OnlineCalibrationNet(nn.Module):
    """Frames in, rig extrinsics out, every frame: ``front_end`` then ``head`` (B rigs of C cameras, as the head's
    ``batch_size`` and ``num_cameras``)."""

    def __init__(self, front_end: FrontEnd, head: OnlineCalibrator):
        super().__init__()
        self.front_end, self.head = front_end, head
        self.reset()

    def reset(self) -> None:
        """Forget the stream: the next frame is frame 0 of every camera."""
        B, C = self.head.batch_size, self.head.num_cameras
        f = dict(dtype=torch.float64, device=self.head.S2.device)
        self.front_end.reset()
        self.head.reset()
        self.head.to(f["device"])  # the head re-creates its state on the device it was built for
        self.register_buffer("trajectory", torch.eye(4, **f).expand(B, C, 4, 4).clone())
        self.register_buffer("rig_rotation", torch.eye(3, **f).expand(B, C - 1, 3, 3).clone())  # the head's R_X

    def forward(self, frame) -> Calibration:
        """Consume one frame (what the front end takes, e.g. images (B, C, 3, H, W) for the network)."""
        motion = self.front_end(frame, self.rig_rotation)
        self.trajectory = self.trajectory @ motion.to(self.trajectory.device, non_blocking=True)
        estimate = self.head(self.trajectory)
        self.rig_rotation = estimate.rotation.detach()
        return estimate
