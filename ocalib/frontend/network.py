"""The pose network as a front end: every camera's motion from a self-supervised ego-motion model.

Each frame, the pose network runs on (previous, current) of every camera of B rigs in one batch; its motions are
optionally refined by direct photometric alignment on the network's depth and re-aligned under the rig's rotation,
and their translations normalised by each camera's running mean step length. Everything stays on one device and
nothing is read back to the host inside a frame; the first frame is handled by masks, not branches.

Convention: ``model.pose(target, source)`` is the pose of the source camera in the target's frame, so
``pose(previous, current) = T_prev_cur`` (:mod:`ocalib.frontend.base`), in the network's units.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor, nn
from torch.utils.data import Dataset

from ocalib.data.sequence import Sequence
from ocalib.frontend import SCALE_MODES
from ocalib.frontend.align import StreamAligner, align_translation
from ocalib.frontend.base import FrontEnd
from ocalib.geometry.pose import invert_pose

# rig-held alignment: Gauss-Newton steps at half, then full resolution (measured: as good as (5, 5, 5), half the time)
RIG_ITERATIONS = (3, 3)
ALIGNED_WARNING = 0.5  # share of frames with an accepted alignment below which a camera is reported (demo: 99-100 %)
# The rotation on planar (car-like) motion, six held-out cars (docs/results-calibrate.md): network front end with
# the rig-held alignment 0.82-2.16 deg, OpenCV VO 0.52-2.49 (five within 2 deg each; OpenCV lower on five).
PLANAR_ADVICE = (
    "planar motion with the network front end: on six held-out cars its rotation was 0.8-2.2 deg off, "
    "OpenCV VO's 0.5-2.5, lower on five of the six; --frontend opencv is worth a try"
)


class NetworkFrontEnd(FrontEnd):
    """Frames of B rigs of C cameras in, every camera's ``T_prev_cur`` out.

    Args:
        model: an ego-motion model with ``pose(target, source) -> (N, 4, 4)`` and ``depth(images)``
            (:class:`ocalib.models.EgoMotionModel`), with its resolution ``height``, ``width``.
        num_cameras: C, cameras per rig. batch_size: B, rigs at once.
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
            (:class:`~ocalib.frontend.align.StreamAligner`; accepted corrections counted in ``aligned``).
        rig_align: with ``align``, re-align the translation of every camera k >= 1 with its rotation held to the
            rig's, R_X^T R_0 R_X (R_0: camera 0's refined rotation, R_X: the calibration's rotation of the previous
            frame), and the depth's inverse tilt solved with it (:func:`~ocalib.frontend.align.align_translation`).
            Camera k's own refined rotation is kept, so the calibration's rotation rows stay independent of R_X; on
            planar motion R_X^T R_0 R_X does not depend on the unobservable yaw (docs/results-calibrate.md).
        views: each camera's :class:`~ocalib.data.model_view.ModelView`, for :meth:`frames`.
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
        views: list | None = None,
    ):
        super().__init__()
        if scale not in SCALE_MODES:
            raise ValueError(f"scale must be one of {SCALE_MODES}, got {scale!r}")
        if align and intrinsics is None:
            raise ValueError("align needs the cameras' intrinsics at the model's resolution")
        self.model, self.scale, self.scale_momentum, self.align = model, scale, scale_momentum, align
        self.rig_align = align and rig_align and num_cameras > 1
        self.uses_rig_rotation = self.rig_align
        if intrinsics is not None:
            intrinsics = torch.as_tensor(intrinsics, dtype=torch.float32)
            if intrinsics.shape not in ((num_cameras, 3, 3), (batch_size, num_cameras, 3, 3)):
                raise ValueError(
                    f"intrinsics must be ({num_cameras}, 3, 3) or ({batch_size}, {num_cameras}, 3, 3), "
                    f"got {tuple(intrinsics.shape)}"
                )
            intrinsics = intrinsics.expand(batch_size, num_cameras, 3, 3).clone()
        self.register_buffer("intrinsics", intrinsics)
        self.aligner = StreamAligner(batch_size * num_cameras)
        self.num_cameras, self.batch_size, self.views = num_cameras, batch_size, views
        self.reset()

    @classmethod
    def for_sequence(cls, sequence: Sequence, options, device: str = "cpu") -> NetworkFrontEnd:
        from ocalib.data.model_view import model_view
        from ocalib.models import load_model

        model = load_model(options.checkpoint).to(device)
        views = [model_view(c, model.height, model.width) for c in sequence.cameras]
        K = np.stack([v.K for v in views])
        front_end = cls(model, len(views), 1, options.scale, intrinsics=K, align=options.align, views=views,
                        rig_align=options.rig_align)  # fmt: skip
        return front_end.to(device)

    def frames(self, sequence: Sequence) -> Dataset:
        from ocalib.data.model_view import FrameImages

        return FrameImages(sequence, self.views)

    def reset(self) -> None:
        B, C = self.batch_size, self.num_cameras
        device = self.previous.device if "previous" in self._buffers else torch.device("cpu")
        self.aligner.reset()
        f = dict(dtype=torch.float64, device=device)
        self.register_buffer("previous", torch.zeros(B, C, 3, self.model.height, self.model.width, device=device))
        self.register_buffer("started", torch.zeros(B, C, 1, 1, dtype=torch.bool, device=device))
        self.register_buffer("step_length", torch.zeros(B, C, **f))  # exponential sums of the step lengths
        self.register_buffer("step_weight", torch.zeros(B, C, **f))  # and of their weights (1 - m^n after n steps)
        self.register_buffer("aligned", torch.zeros(B, C, dtype=torch.long, device=device))

    def forward(self, images: Tensor, rig_rotation: Tensor) -> Tensor:
        """images: (B, C, 3, H, W) or (C, 3, H, W) in [0, 1] at the model's resolution (``model.height``,
        ``model.width``) -> motions (B, C, 4, 4) float64."""
        images = images.to(self.previous.device, non_blocking=True)
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
            step = self._align(previous.flatten(0, 1), images.flatten(0, 1), step, rig_rotation)
        step = torch.where(self.started, step, torch.eye(4, dtype=step.dtype, device=step.device))
        if self.scale == "normalise":
            step = self._normalise(step)
        self.previous = images.detach()
        self.started = torch.ones_like(self.started)
        return step

    def report(self, names: list[str], frames: int, estimate) -> tuple[dict, list[str]]:
        """The accepted photometric corrections per camera (frame 0 has none), and warnings: a camera whose motions
        the alignment mostly kept, and planar motion, where OpenCV VO was measured better."""
        settings, warnings = {}, []
        if self.align:
            settings["aligned_frames"] = dict(zip(names, self.aligned[0].tolist()))
            warnings += [
                f"{name}: the photometric alignment kept the network's motion on {frames - 1 - n} of {frames - 1} "
                "frames (textureless images, wrong intrinsics or a poor depth network?)"
                for name, n in settings["aligned_frames"].items()
                if n < ALIGNED_WARNING * (frames - 1)
            ]
        planar = [] if estimate is None else estimate.planar_motion[0].tolist()
        warnings += [f"{name}: {PLANAR_ADVICE}" for name, flat in zip(names[1:], planar) if flat]
        return settings, warnings

    def _align(self, previous: Tensor, images: Tensor, step: Tensor, rig_rotation: Tensor) -> Tensor:
        """``step`` (B, C, 4, 4) = ``T_prev_cur`` refined photometrically on the previous frames' depth."""
        K = self.intrinsics.flatten(0, 1)
        depth = self.model.depth(previous)
        T, accepted = self.aligner(previous, images, depth, K, invert_pose(step.flatten(0, 1)))
        self.aligned = self.aligned + (accepted.view_as(self.aligned) & self.started[..., 0, 0])
        step = invert_pose(T).view_as(step)
        return self._rig_align(previous, images, depth, K, step, rig_rotation) if self.rig_align else step

    def _rig_align(self, previous, images, depth, K, step: Tensor, rig_rotation: Tensor) -> Tensor:
        """``step`` (B, C, 4, 4) with the translation of cameras k >= 1 re-aligned under the rig's rotation
        R_X^T R_0 R_X; their own rotations are kept, and so is their translation where the result is not finite
        (a non-finite motion or extrinsic)."""
        B, C = self.batch_size, self.num_cameras
        others = lambda x: x.view(B, C, *x.shape[1:])[:, 1:].flatten(0, 1)  # noqa: E731
        R = rig_rotation.to(step.dtype)
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
