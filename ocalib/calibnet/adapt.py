"""On-line adaptation of the pose network on a new rig (``ocalib calibrate --adapt``).

Each frame, before the calibration net consumes it, one gradient step on the pose network's weights
lowers (a) the photometric error of warping each camera's previous frame into its current one with the
(frozen) depth network and the predicted motion, and (b) the rig constraint: with the head's current
extrinsic ``(dR, dT, s)`` the motions of camera 0 and camera k must satisfy the hand-eye equations
``R0 dR = dR Rk`` and ``(R0 - I) dT + t0 = s dR tk``. The rig term only counts once the head's rotation
is observable (a mask, not a branch: no host round-trip).

Convention: ``model.pose(prev, cur) = T_prev_cur`` (``p_prev = T p_cur``), which is also the
``T_source_target`` that warps the previous frame (source) into the current one (target);
``T_cam0_camk`` as in :class:`~ocalib.calib.result.Calibration`. K (C, 3, 3) at the model's resolution.
"""

from __future__ import annotations

import torch
from torch import Tensor

from ocalib.calib.result import Calibration
from ocalib.losses import inverse_warp, photometric_error


def rig_residual(motion: Tensor, dR: Tensor, dT: Tensor, s: Tensor) -> Tensor:
    """Hand-eye residual of the motions (C, 4, 4) of one rig under the extrinsics ``dR`` (K, 3, 3), ``dT`` (K, 3)
    and scales ``s`` (K,) -> (K,) squared norms, K = C - 1.

    Rotation part in Frobenius norm; translation part divided by camera 0's squared step length so that
    the two terms are comparable.
    """
    R0, t0 = motion[:1, :3, :3], motion[:1, :3, 3]
    Rk, tk = motion[1:, :3, :3], motion[1:, :3, 3]
    rotation = (R0 @ dR - dR @ Rk).square().sum((-2, -1))
    eye = torch.eye(3, dtype=motion.dtype, device=motion.device)
    translation = ((R0 - eye) @ dT[..., None])[..., 0] + t0 - s[:, None] * (dR @ tk[..., None])[..., 0]
    return rotation + translation.square().sum(-1) / t0.square().sum().clamp_min(1e-12)


class PoseAdapter:
    """One Adam step per frame on ``model.pose_net`` (learning rate ``lr``, rig-term weight ``rig_weight``)."""

    def __init__(self, model, K: Tensor, lr: float = 1e-5, rig_weight: float = 0.1):
        self.model, self.K, self.rig_weight = model, K, rig_weight
        self.optimizer = torch.optim.Adam(model.pose_net.parameters(), lr=lr)
        self.last_loss: dict[str, float] = {}

    def step(self, previous: Tensor, images: Tensor, estimate: Calibration | None) -> Tensor:
        """previous, images: (C, 3, H, W). Returns the loss (a 0-d tensor, detached)."""
        with torch.inference_mode(False), torch.enable_grad():
            previous, images = previous.clone(), images.clone()  # normal tensors, usable by autograd
            K = self.K.to(images.device, images.dtype)
            with torch.no_grad():
                depth = self.model.depth(images)
            self.model.pose_net.train(False)
            motion = self.model.pose(previous, images)  # T_prev_cur = T_source_target
            warp = inverse_warp(previous, depth, motion, K)
            error = photometric_error(warp.image, images)
            photometric = (error * warp.mask).sum() / warp.mask.sum().clamp_min(1)
            loss = photometric
            if estimate is not None:  # the head's tensors may be inference tensors: clone them for autograd
                dR, dT, s, observable = (x[0].clone().double() for x in (
                    estimate.rotation, estimate.translation, estimate.scale, estimate.rotation_observable))
                rig = (observable * rig_residual(motion.double(), dR, dT, s)).sum()
                loss = loss + self.rig_weight * rig.float()
            self.optimizer.zero_grad(set_to_none=True)
            loss.backward()
            self.optimizer.step()
        return loss.detach()
