"""The on-line calibration net: a pose network and the calibration head on one graph.

Each call takes one synchronised set of frames of every camera of B rigs, runs the pose network on
(previous, current) of every camera in one batch, chains the motions into each camera's trajectory and
updates the head (:class:`~ocalib.calib.online.OnlineCalibrator`). Everything stays on one device and
nothing is read back to the host inside a frame; the first frame is handled by masks, not branches.

Convention: ``model.pose(target, source)`` is the pose of the source camera in the target's frame, so
``pose(previous, current) = T_prev_cur`` and a camera's trajectory is ``T_first_cur = T_first_prev T_prev_cur``
(camera-to-first-frame, in the network's units). The head returns ``T_cam0_camk`` (``p_cam0 = R p_camk + t``)
in camera 0's network units and the scale that maps camera k's network units into camera 0's.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from ocalib.calib.online import OnlineCalibrator
from ocalib.calib.result import Calibration
from ocalib.frontend.align import StreamAligner, align_translation
from ocalib.geometry.pose import invert_pose

SCALE_MODES = ("head", "normalise")
# rig-held alignment: Gauss-Newton steps at half, then full resolution (measured: as good as (5, 5, 5), half the time)
RIG_ITERATIONS = (3, 3)


class OnlineCalibrationNet(nn.Module):
    """Frames in, rig extrinsics out, every frame.

    Args:
        model: an ego-motion model with ``pose(target, source) -> (N, 4, 4)`` (:class:`ocalib.models.EgoMotionModel`).
        num_cameras: C, cameras per rig (camera 0 the reference).
        batch_size: B, rigs calibrated at once.
        scale: how the network's translation scale is handled. ``head``: trust each camera's network scale to
            be consistent over time and let the head's scale unknown absorb the ratio between cameras.
            ``normalise``: divide every step by a running mean of that camera's step lengths (exponential, momentum
            ``scale_momentum``, its start-up bias divided out), for networks whose scale drifts slowly. The mean's
            window (1 / (1 - momentum) frames) must be long beside a turn: in a turn a camera off the rig's axis
            steps longer or shorter than camera 0 (the lever arm), which is what the translation is solved from, and
            a short window normalises it away (the exact motions of the eleven held-out rigs: a median 21 deg of
            translation direction at 0.95, 4.1 at 0.99; docs/calibnet.md).
        intrinsics: (C, 3, 3) or (B, C, 3, 3) pixels at the model's resolution; needed by ``align``.
        align: refine every motion of the network by direct photometric alignment on the network's depth of the
            previous frame, started from the network's motion and from the camera's previous refined motion
            (:class:`~ocalib.frontend.align.StreamAligner`; accepted corrections counted in ``aligned``); rotation
            and translation both (docs/results-calibrate.md).
        rig_align: with ``align``, re-align the translation of every camera k >= 1 with its rotation held to the
            rig's, R_X^T R_0 R_X (R_0: camera 0's refined rotation, R_X: the head's estimate of the previous frame),
            and the depth's inverse tilt solved with it (:func:`~ocalib.frontend.align.align_translation`). The
            head still gets camera k's own refined rotation, so its rotation rows stay independent of R_X; on
            planar motion R_X^T R_0 R_X does not depend on the unobservable yaw. Measured on the held-out cars
            (docs/results-calibrate.md).
        head_options: passed to :class:`OnlineCalibrator` (``motion``, ``solver``, ``forgetting``, ...).
    """

    def __init__(
        self,
        model: nn.Module,
        num_cameras: int = 2,
        batch_size: int = 1,
        scale: str = "head",
        scale_momentum: float = 0.99,
        intrinsics: Tensor | None = None,
        align: bool = False,
        rig_align: bool = True,
        **head_options,
    ):
        super().__init__()
        if scale not in SCALE_MODES:
            raise ValueError(f"scale must be one of {SCALE_MODES}, got {scale!r}")
        if align and intrinsics is None:
            raise ValueError("align needs the cameras' intrinsics at the model's resolution")
        self.model, self.scale, self.scale_momentum, self.align = model, scale, scale_momentum, align
        self.rig_align = align and rig_align and num_cameras > 1
        if intrinsics is not None:
            intrinsics = torch.as_tensor(intrinsics, dtype=torch.float32)
            if intrinsics.shape not in ((num_cameras, 3, 3), (batch_size, num_cameras, 3, 3)):
                raise ValueError(
                    f"intrinsics must be ({num_cameras}, 3, 3) or ({batch_size}, {num_cameras}, 3, 3), "
                    f"got {tuple(intrinsics.shape)}"
                )
            intrinsics = intrinsics.expand(batch_size, num_cameras, 3, 3).clone()
        self.register_buffer("intrinsics", intrinsics)
        self.head = OnlineCalibrator(num_cameras, batch_size, **head_options)
        self.aligner = StreamAligner(batch_size * num_cameras)
        self.num_cameras, self.batch_size = num_cameras, batch_size
        self.reset()

    def reset(self) -> None:
        """Forget the stream: the next frame is frame 0 of every camera."""
        B, C = self.batch_size, self.num_cameras
        f = dict(dtype=torch.float64, device=self.head.S2.device)
        self.head.reset()
        self.aligner.reset()
        self.head.to(f["device"])  # the head re-creates its state on the device it was built for
        self.register_buffer("previous", torch.zeros(B, C, 3, self.model.height, self.model.width, device=f["device"]))
        self.register_buffer("started", torch.zeros(B, C, 1, 1, dtype=torch.bool, device=f["device"]))
        self.register_buffer("trajectory", torch.eye(4, **f).expand(B, C, 4, 4).clone())
        self.register_buffer("step_length", torch.zeros(B, C, **f))  # exponential sums of the step lengths
        self.register_buffer("step_weight", torch.zeros(B, C, **f))  # and of their weights (1 - m^n after n steps)
        self.register_buffer("aligned", torch.zeros(B, C, dtype=torch.long, device=f["device"]))
        self.register_buffer("rig_rotation", torch.eye(3, **f).expand(B, C - 1, 3, 3).clone())  # the head's R_X

    def forward(self, images: Tensor) -> Calibration:
        """Consume one frame. images: (B, C, 3, H, W) or (C, 3, H, W) in [0, 1], at the model's resolution
        (``model.height``, ``model.width``)."""
        if images.dim() == 4:
            images = images.unsqueeze(0)
        B, C = self.batch_size, self.num_cameras
        if images.shape != self.previous.shape:
            raise ValueError(
                f"expected images of shape {tuple(self.previous.shape)} (B, C, 3, H, W at the model's "
                f"resolution), got {tuple(images.shape)}"
            )
        previous = torch.where(self.started.unsqueeze(-1), self.previous, images)
        step = self.model.pose(previous.flatten(0, 1), images.flatten(0, 1)).view(B, C, 4, 4).to(torch.float64)
        if self.align:
            step = self._align(previous.flatten(0, 1), images.flatten(0, 1), step)
        step = torch.where(self.started, step, torch.eye(4, dtype=step.dtype, device=step.device))
        if self.scale == "normalise":
            step = self._normalise(step)
        self.trajectory = self.trajectory @ step
        self.previous = images.detach()
        self.started = torch.ones_like(self.started)
        estimate = self.head(self.trajectory)
        self.rig_rotation = estimate.rotation.detach()
        return estimate

    def _align(self, previous: Tensor, images: Tensor, step: Tensor) -> Tensor:
        """``step`` (B, C, 4, 4) = ``T_prev_cur`` refined photometrically on the previous frames' depth."""
        K = self.intrinsics.flatten(0, 1)
        depth = self.model.depth(previous)
        T, accepted = self.aligner(previous, images, depth, K, invert_pose(step.flatten(0, 1)))
        self.aligned = self.aligned + (accepted.view_as(self.aligned) & self.started[..., 0, 0])
        step = invert_pose(T).view_as(step)
        return self._rig_align(previous, images, depth, K, step) if self.rig_align else step

    def _rig_align(self, previous: Tensor, images: Tensor, depth: Tensor, K: Tensor, step: Tensor) -> Tensor:
        """``step`` (B, C, 4, 4) with the translation of cameras k >= 1 re-aligned under the rig's rotation
        R_X^T R_0 R_X; their own rotations are kept, and so is their translation where the result is not finite
        (a non-finite motion or extrinsic)."""
        B, C = self.batch_size, self.num_cameras
        others = lambda x: x.view(B, C, *x.shape[1:])[:, 1:].flatten(0, 1)
        R = self.rig_rotation.to(step.dtype)
        start = step[:, 1:].clone()
        start[..., :3, :3] = R.transpose(-1, -2) @ step[:, :1, :3, :3] @ R
        T, _ = align_translation(
            others(previous), others(images), others(depth), others(K), invert_pose(start.flatten(0, 1)), RIG_ITERATIONS
        )
        translation = invert_pose(T).view_as(start)[..., :3, 3]
        out = step.clone()
        out[:, 1:, :3, 3] = torch.where(translation.isfinite().all(-1, keepdim=True), translation, step[:, 1:, :3, 3])
        return out

    def _normalise(self, step: Tensor) -> Tensor:
        """Express each step's translation in units of that camera's running mean step length: an exponential
        mean with its start-up bias divided out (``step_length / step_weight``), so the first steps are averaged
        alike rather than the first one standing for the mean until the window forgets it (the network's first
        step can be several times its typical one)."""
        length = step[..., :3, 3].norm(dim=-1)
        m, started = self.scale_momentum, self.started[..., 0, 0]
        self.step_length = torch.where(started, m * self.step_length + (1 - m) * length, self.step_length)
        self.step_weight = torch.where(started, m * self.step_weight + (1 - m), self.step_weight)
        mean = self.step_length / self.step_weight.clamp_min(1 - m)
        unit = torch.where(mean > 0, mean, torch.ones_like(mean))
        out = step.clone()
        out[..., :3, 3] = step[..., :3, 3] / unit[..., None]
        return out
