"""Running an ego-motion model over a sequence: batched depth and frame-to-frame poses for every camera.

:func:`predict_frames` yields, frame by frame, every camera's depth map and motion ``T_{t-1,t}``;
:func:`chain` turns the motions into a trajectory. Images reach the model through a :class:`ModelView`:
centre-cropped to the model's aspect ratio (when it differs by more than 1%) and resized to its resolution,
with K updated accordingly.

Convention: ``T_{t-1,t}`` is the pose of frame t's camera in frame t-1's camera frame (``p_{t-1} = T p_t``,
``model.pose(target=t-1, source=t)``), identity for frame 0; chained, ``P_t = P_{t-1} T_{t-1,t}`` is
camera-to-first-frame. Depth and translations are in network units.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torch.utils.data import DataLoader, Dataset
from tqdm import tqdm

from ocalib.data.image_io import read_image
from ocalib.data.intrinsics import crop_intrinsics, resize_intrinsics
from ocalib.data.sequence import Camera, Sequence
from ocalib.data.static import thumbnails
from ocalib.errors import InputError
from ocalib.frontend.align import StreamAligner
from ocalib.geometry.pose import invert_pose

MAX_UPSAMPLE = 4.0  # a camera whose (cropped) images are this much smaller than the model's resolution is refused
STATIC_THRESHOLD = 1e-3  # mean absolute grey difference below which two frames count as identical
STATIC_SAMPLES = 8  # frames compared with the first by :func:`check_motion`


@dataclass(frozen=True)
class ModelView:
    """How one camera's images are fed to the model: the crop ``(x0, y0, width, height)`` of the original
    image, resized to ``size`` (H, W); ``K`` (3, 3) float64 the intrinsics at ``size``."""

    crop: tuple[int, int, int, int]
    size: tuple[int, int]
    K: np.ndarray

    def image(self, path, camera_size: tuple[int, int]) -> torch.Tensor:
        """Read one image of the camera (its size checked against ``camera_size``) -> (3, H, W) float32."""
        x0, y0, w, h = self.crop
        if (h, w) == tuple(camera_size):  # no crop: the same resize as training (cv2, area when shrinking)
            return read_image(path, camera_size, self.size)
        image = read_image(path, camera_size)[:, y0 : y0 + h, x0 : x0 + w]
        shrink = self.size[0] < h or self.size[1] < w
        return F.interpolate(image[None], self.size, mode="bilinear", align_corners=False, antialias=shrink)[0].clamp(
            0, 1
        )


def model_view(camera: Camera, height: int, width: int) -> ModelView:
    """The :class:`ModelView` of ``camera`` for a model of resolution (height, width).

    Raises InputError when the crop would have to be upsampled more than :data:`MAX_UPSAMPLE` times.
    """
    H, W = camera.size
    aspect = width / height
    x0, y0, w, h = 0, 0, W, H
    if W / H > aspect * 1.01:
        w = max(1, round(H * aspect))
        x0 = (W - w) // 2
    elif W / H < aspect / 1.01:
        h = max(1, round(W / aspect))
        y0 = (H - h) // 2
    if height / h > MAX_UPSAMPLE or width / w > MAX_UPSAMPLE:
        where = camera.images[0].parent if camera.images else camera.name
        raise InputError(
            f"{where}: images of {H}x{W} (HxW) are too small for the model's {height}x{width} "
            f"(the usable {h}x{w} crop would be upsampled more than {MAX_UPSAMPLE:g}x)"
        )
    K = crop_intrinsics(torch.from_numpy(np.asarray(camera.K, dtype=np.float64)), x0, y0)
    K = resize_intrinsics(K, (h, w), (height, width)).numpy()
    return ModelView((x0, y0, w, h), (height, width), K)


def check_motion(sequence: Sequence, samples: int = STATIC_SAMPLES) -> None:
    """Raise InputError when a camera's frames all look the same (no motion: ego-motion is undefined).

    Compares grey thumbnails of up to ``samples`` evenly spaced frames with the first one; also refuses
    sequences of fewer than 2 frames.
    """
    if len(sequence) < 2:
        raise InputError(f"{sequence.path}: {len(sequence)} frame(s); ego-motion needs at least 2")
    index = np.unique(np.linspace(0, len(sequence) - 1, min(samples, len(sequence))).round().astype(int))
    for cam in sequence.cameras:
        thumbs = thumbnails([cam.images[i] for i in index])
        change = float((thumbs[1:] - thumbs[:1]).abs().mean((-2, -1)).max())
        if change < STATIC_THRESHOLD:
            raise InputError(
                f"{cam.images[0].parent}: camera {cam.name} shows no motion (frames "
                f"{', '.join(map(str, index))} of {len(sequence)} are identical, mean difference "
                f"{change:.2g}); ego-motion cannot be estimated from a still camera"
            )


class FrameImages(Dataset):
    """Frame t of every camera through its view -> (C, 3, H, W) float32."""

    def __init__(self, sequence: Sequence, views: list[ModelView]):
        self.sequence, self.views = sequence, views

    def __len__(self) -> int:
        return len(self.sequence)

    def __getitem__(self, t: int) -> torch.Tensor:
        return torch.stack([v.image(c.images[t], c.size) for c, v in zip(self.sequence.cameras, self.views)])


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
    batch_size: int = 8,
    depth: bool = True,
    workers: int = 0,
    progress: bool | None = False,
    align: bool = False,
    flip: bool = False,
) -> Iterator[FramePrediction]:
    """Run ``model`` (an :class:`ocalib.models.EgoMotionModel`) over every frame of every camera.

    Each forward pass takes ``batch_size`` frames of all C cameras: C x batch_size pose pairs (t-1, t) and
    depth maps, under ``torch.inference_mode`` on ``device``. ``workers``: DataLoader processes reading
    images. ``progress``: a tqdm bar over frames (None: only on a terminal). Yields :class:`FramePrediction`
    in frame order. Checks the sequence for motion first (:func:`check_motion`). ``flip``: the depth maps (those
    written and those the alignment uses) averaged with the mirrored image's (:meth:`EgoMotionModel.depth`).
    """
    if batch_size < 1:
        raise InputError(f"batch size must be >= 1, got {batch_size}")
    views = [model_view(cam, model.height, model.width) for cam in sequence.cameras]
    check_motion(sequence)
    loader = DataLoader(FrameImages(sequence, views), batch_size=batch_size, num_workers=workers)
    K = torch.from_numpy(np.stack([v.K for v in views])).float().to(device) if align else None
    return _generate(model.to(device).eval(), loader, len(sequence), device, depth, progress, K, flip)


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


def chain(motions: np.ndarray) -> np.ndarray:
    """Frame-to-frame motions (N, 4, 4) (``motions[0]`` ignored, frame 0 is the identity) -> poses (N, 4, 4)
    camera-to-first-frame, ``P_t = P_{t-1} T_{t-1,t}``."""
    poses = np.empty_like(motions, dtype=np.float64)
    poses[0] = np.eye(4)
    for t in range(1, len(motions)):
        poses[t] = poses[t - 1] @ motions[t]
    return poses
