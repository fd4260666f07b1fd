"""Running an ego-motion model over a sequence: batched depth and frame-to-frame poses for every camera.

:func:`predict_frames` yields, frame by frame, every camera's depth map and motion ``T_{t-1,t}``
(:func:`~ocalib.geometry.se3.chain_motions` turns the motions into a trajectory). Images reach the model through
a :class:`~ocalib.data.model_view.ModelView`.

Convention: ``T_{t-1,t}`` is the pose of frame t's camera in frame t-1's camera frame (``p_{t-1} = T p_t``,
``model.pose(target=t-1, source=t)``), identity for frame 0; chained, ``P_t = P_{t-1} T_{t-1,t}`` is
camera-to-first-frame. Depth and translations are in network units.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import torch
from torch.utils.data import DataLoader
from tqdm import tqdm

from ocalib.data.model_view import FrameImages, model_view
from ocalib.data.sequence import Sequence
from ocalib.data.static import check_motion
from ocalib.errors import InputError
from ocalib.frontend.align import StreamAligner
from ocalib.geometry.pose import invert_pose


@dataclass(frozen=True)
class PredictOptions:
    """How :func:`predict_frames` runs: ``batch_size`` frames of all C cameras a forward pass; ``depth``: return the
    depth maps; ``workers``: DataLoader processes reading images; ``align``: refine each motion by direct photometric
    alignment on the network's depth of the previous frame; ``flip``: the depth maps (those returned and those the
    alignment uses) averaged with the mirrored image's (:meth:`EgoMotionModel.depth`)."""

    batch_size: int = 8
    depth: bool = True
    workers: int = 0
    align: bool = False
    flip: bool = False


@dataclass
class FramePrediction:
    """The model's output for frame ``frame`` of every camera (cameras in the sequence's order).

    motion: (C, 4, 4) float64 ``T_{t-1,t}`` (identity at frame 0). depth: (C, H, W) float32, network
    units, at the model's resolution, or None when depth was not asked for.
    """

    frame: int
    motion: np.ndarray
    depth: np.ndarray | None


def predict_frames(
    model,
    sequence: Sequence,
    device: str | torch.device = "cpu",
    options: PredictOptions = PredictOptions(),
    progress: bool | None = False,
) -> Iterator[FramePrediction]:
    """Run ``model`` (an :class:`ocalib.models.EgoMotionModel`) over every frame of every camera.

    Each forward pass takes ``options.batch_size`` frames of all C cameras: C x batch_size pose pairs (t-1, t) and
    depth maps, under ``torch.inference_mode`` on ``device``. ``progress``: a tqdm bar over frames (None: only on a
    terminal). Yields :class:`FramePrediction` in frame order. Checks the sequence for motion first
    (:func:`check_motion`).
    """
    if options.batch_size < 1:
        raise InputError(f"batch size must be >= 1, got {options.batch_size}")
    views = [model_view(cam, model.height, model.width) for cam in sequence.cameras]
    check_motion(sequence)
    loader = DataLoader(FrameImages(sequence, views), batch_size=options.batch_size, num_workers=options.workers)
    K = torch.from_numpy(np.stack([v.K for v in views])).float().to(device) if options.align else None
    model = model.to(device).eval()
    return _generate(model, loader, len(sequence), device, options.depth, progress, K, options.flip)


def _generate(model, loader, frames: int, device, depth: bool, progress, K, flip: bool) -> Iterator[FramePrediction]:
    previous, t = None, 0
    aligner = StreamAligner(len(K)).to(K.device) if K is not None else None
    with tqdm(total=frames, unit="frame", desc="predicting", disable=None if progress is None else not progress) as bar:
        for images in loader:  # (b, C, 3, H, W)
            motion, depth_maps, previous = _predict_batch(model, images.to(device), previous, depth, K, aligner, flip)
            for i in range(len(images)):
                yield FramePrediction(t, motion[i], None if depth_maps is None else depth_maps[i])
                t += 1
            bar.update(len(images))


def _predict_batch(
    model,
    images: torch.Tensor,
    previous: tuple | None,
    depth: bool,
    K: torch.Tensor | None,
    aligner: StreamAligner | None,
    flip: bool = False,
):
    """One batch of frames.

    Args:
        images: (b, C, 3, H, W). previous: the frame before the batch, ``(images (C, 3, H, W), depth (C, 1, H, W)
            or None)``, or None at the start. depth: return the depth maps. K: (C, 3, 3) at the model's
            resolution: align the motions on the network's depth of each pair's first frame, frame after frame
            with ``aligner`` (its state carries over between batches; None: the network's motions as they are).
            flip: test-time flipping of the depth (:meth:`EgoMotionModel.depth`).

    Returns motions (b, C, 4, 4) float64, depth (b, C, H, W) float32 or None, and the batch's last frame as the
    next call's ``previous``. Each frame's depth is computed once, whether for the output or for the alignment.
    """
    b, C = images.shape[:2]
    with torch.inference_mode():
        maps = model.depth(images.flatten(0, 1), flip).unflatten(0, (b, C)) if depth or K is not None else None
        targets = images[:-1] if previous is None else torch.cat([previous[0][None], images[:-1]])
        sources = images[b - len(targets) :]
        motion = torch.eye(4, dtype=torch.float64).repeat(b, C, 1, 1)
        if len(targets):
            T = model.pose(targets.flatten(0, 1), sources.flatten(0, 1))
            if K is not None:
                target_depth = maps[:-1] if previous is None else torch.cat([previous[1][None], maps[:-1]])
                T = torch.stack(
                    [
                        invert_pose(aligner(*pair, K, invert_pose(net))[0])
                        for *pair, net in zip(targets, sources, target_depth, T.view(-1, C, 4, 4))
                    ]
                )
            motion[b - len(targets) :] = T.view(-1, C, 4, 4).double().cpu()
    depth_maps = maps.squeeze(2).float().cpu().numpy() if depth else None
    return motion.numpy(), depth_maps, (images[-1], None if maps is None else maps[-1])
