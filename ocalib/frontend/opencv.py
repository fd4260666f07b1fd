"""OpenCV monocular VO as a front end: one :class:`~ocalib.frontend.opencv_vo.OpenCVOdometry` per camera, the
cameras of a frame stepped on threads of their own (OpenCV's tracking and the window's compiled kernel release the
GIL, so they share the cores; each camera's odometry is independent, so the motions do not depend on it).

Convention: as :mod:`ocalib.frontend.base`; each camera at its own image size and intrinsics, in units of its own
(the first moving pair's length).
"""

from __future__ import annotations

import functools
import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import torch
from torch import Tensor
from torch.utils.data import Dataset

from ocalib.data.sequence import Sequence
from ocalib.frontend.base import FrontEnd
from ocalib.frontend.opencv_vo import OpenCVOdometry

LOST_WARNING = 0.05  # share of a camera's frames without tracks from which calibrate warns


class GreyFrames(Dataset):
    """Frame t of every camera at its own size -> a list of C (H, W) uint8 grey images."""

    def __init__(self, sequence: Sequence):
        self.sequence = sequence

    def __len__(self) -> int:
        return len(self.sequence)

    def __getitem__(self, t: int) -> list[Tensor]:
        return [torch.from_numpy(c.read_grey(t)) for c in self.sequence.cameras]


class OpenCVFrontEnd(FrontEnd):
    """One rig of C cameras with intrinsics ``K`` (C, 3, 3) pixels at their images' sizes; ``options``: the VO's
    (:class:`~ocalib.frontend.opencv_vo.OpenCVOdometry`)."""

    uses_rig_rotation = False

    def __init__(self, K: np.ndarray, **options):
        super().__init__()
        self.K, self.options = np.asarray(K, dtype=np.float64), options
        self.reset()

    @classmethod
    def for_sequence(cls, sequence: Sequence, options=None, device: str = "cpu") -> OpenCVFrontEnd:
        return cls(np.stack([c.K for c in sequence.cameras]))

    def frames(self, sequence: Sequence) -> Dataset:
        return GreyFrames(sequence)

    def reset(self) -> None:
        self.odometry = [OpenCVOdometry(K, **self.options) for K in self.K]
        self.lost = np.zeros(len(self.K), int)  # frames each camera lost its tracks on

    def forward(self, images: list[Tensor], rig_rotation: Tensor | None = None) -> Tensor:
        """images: C grey images (H, W) uint8 (or anything :class:`OpenCVOdometry` reads) -> (1, C, 4, 4) float64."""
        steps = list(_threads().map(_step, self.odometry, images))
        self.lost += [vo.status.reason == "too few tracks" for vo in self.odometry]
        return torch.from_numpy(np.stack(steps))[None]

    def report(self, names: list[str], frames: int, estimate) -> tuple[dict, list[str]]:
        """The frames each camera lost its tracks on, and a warning for a camera that lost ``LOST_WARNING`` of them
        or more (their steps are guesses: the last measured one again)."""
        lost = dict(zip(names, self.lost.tolist()))
        warnings = [
            f"{name}: the OpenCV front end lost its tracks on {n} of {frames} frames (the view blocked, or a blank "
            "wall close by); their motion is the last measured one again, a guess"
            for name, n in lost.items()
            if n >= LOST_WARNING * frames
        ]
        return {"lost_frames": lost}, warnings


def _step(odometry: OpenCVOdometry, image) -> np.ndarray:
    return odometry.step(np.asarray(image))


@functools.cache
def _threads() -> ThreadPoolExecutor:
    """The threads the cameras' odometry steps run on, one a core this process may use."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    return ThreadPoolExecutor(max_workers=cores, thread_name_prefix="ocalib-opencv-vo")
