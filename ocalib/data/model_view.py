"""How a camera's images reach an ego-motion model: centre-cropped to the model's aspect ratio (when it differs by
more than 1%) and resized to its resolution, with K updated accordingly.

Convention: K (3, 3) in pixels with integer pixel centres, updated with the crop and the resize.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torch.utils.data import Dataset

from ocalib.data.intrinsics import crop_intrinsics, resize_intrinsics
from ocalib.data.sequence import Camera, Sequence
from ocalib.errors import InputError

MAX_UPSAMPLE = 4.0  # a camera whose (cropped) images are this much smaller than the model's resolution is refused


@dataclass(frozen=True)
class ModelView:
    """How one camera's images are fed to the model: the crop ``(x0, y0, width, height)`` of the original
    image, resized to ``size`` (H, W); ``K`` (3, 3) float64 the intrinsics at ``size``."""

    crop: tuple[int, int, int, int]
    size: tuple[int, int]
    K: np.ndarray

    def image(self, camera: Camera, t: int) -> torch.Tensor:
        """Frame t of ``camera`` (:meth:`~ocalib.data.sequence.Camera.read`: undistorted where it has a lens
        distortion) through the view -> (3, H, W) float32."""
        x0, y0, w, h = self.crop
        if (h, w) == tuple(camera.size):  # no crop: the same resize as training (cv2, area when shrinking)
            return camera.read(t, self.size)
        image = camera.read(t)[:, y0 : y0 + h, x0 : x0 + w]
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


class FrameImages(Dataset):
    """Frame t of every camera through its view -> (C, 3, H, W) float32."""

    def __init__(self, sequence: Sequence, views: list[ModelView]):
        self.sequence, self.views = sequence, views

    def __len__(self) -> int:
        return len(self.sequence)

    def __getitem__(self, t: int) -> torch.Tensor:
        return torch.stack([v.image(c, t) for c, v in zip(self.sequence.cameras, self.views)])
