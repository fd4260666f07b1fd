"""The common description every layout loader returns: a :class:`Sequence` of synchronised cameras.

Convention: poses are camera-to-world 4x4 float64 (one world frame per sequence); ``T_cam0_cam`` is the
pose of a camera in the frame of the sequence's first camera (``p_cam0 = R p_cam + t``), the identity
for that camera; K (3, 3) float64 in pixels (integer pixel centres) at the image size ``size`` (H, W).
Frame t of every camera is the same instant, unless the cameras have stamps of their own (``times``, each on its own
clock, each camera then with its own number of frames): :func:`ocalib.data.synchronise.synchronise` pairs the frames. A camera's ``change`` (:class:`~ocalib.data.rig.ExtrinsicChange`)
is its true ``T_cam0_cam`` from frame ``change.frame`` on, where it was moved mid-sequence; ``T_cam0_cam``
holds before that frame. A camera's ``distortion`` is its lens's (None: a pinhole); :meth:`Camera.read` gives its frames
as the front ends see them, undistorted for K.
"""

from __future__ import annotations

import typing
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ocalib.data.distortion import Distortion, undistort_image
from ocalib.data.image_io import decode_image, grey_image, image_tensor, read_image, resize_image
from ocalib.data.rig import ExtrinsicChange
from ocalib.errors import InputError

if typing.TYPE_CHECKING:
    from torch import Tensor

    from ocalib.data.synchronise import Pairing


@dataclass
class Camera:
    """One camera of a sequence: N image paths and what the layout knows about them."""

    name: str
    images: list[Path]  # N files
    K: np.ndarray  # (3, 3) float64, pixels, at `size`
    size: tuple[int, int]  # (H, W)
    T_cam0_cam: np.ndarray | None = None  # (4, 4) float64, when the layout knows the extrinsics (at frame 0)
    poses: np.ndarray | None = None  # (N, 4, 4) float64 camera-to-world ground truth
    depth: list[Path] | None = None  # N uint16 PNGs, metres x depth_scale, 0 = no surface
    depth_scale: float = 256.0
    change: ExtrinsicChange | None = None  # the true extrinsic from a later frame on, where the camera moved
    distortion: Distortion | None = None  # the lens's, None for a pinhole
    times: np.ndarray | None = None  # (N,) seconds on the camera's own clock, where it has one
    time_offset: float | None = None  # the true t0 - t of its clock, seconds, where known (rendered rigs)

    def __len__(self) -> int:
        return len(self.images)

    def at(self, frames: np.ndarray) -> Camera:
        """The camera at its frames ``frames`` (M,) int, increasing: images, poses, depth, stamps and the frame of a
        change re-indexed (a change before the first frame kept is the extrinsic, one after the last is dropped)."""
        change, T = self.change, self.T_cam0_cam
        if change is not None:
            after = np.flatnonzero(frames >= change.frame)
            if not len(after):  # moved after the last frame kept
                change = None
            elif after[0] == 0:  # moved before the first frame kept
                change, T = None, change.T_cam0_cam
            else:
                change = ExtrinsicChange(int(after[0]), change.T_cam0_cam)
        return replace(
            self,
            T_cam0_cam=T,
            images=[self.images[j] for j in frames],
            poses=None if self.poses is None else self.poses[frames],
            depth=None if self.depth is None else [self.depth[j] for j in frames],
            times=None if self.times is None else self.times[frames],
            change=change,
        )

    def read(self, t: int, out_size: tuple[int, int] | None = None) -> Tensor:
        """Frame t as the front ends see it -> (3, H, W) float32 in [0, 1]: the pinhole image of K (undistorted
        where the camera has a distortion, by a remap cached per camera), resized to ``out_size`` (H', W') if given."""
        if self.distortion is None:
            return read_image(self.images[t], self.size, out_size)
        array = undistort_image(decode_image(self.images[t], self.size), self.K, self.distortion)
        return image_tensor(resize_image(array, out_size))

    def read_grey(self, t: int) -> np.ndarray:
        """Frame t as :meth:`read` gives it at its own size, in 8-bit grey -> (H, W) uint8 (:func:`grey_image`)."""
        array = decode_image(self.images[t], self.size)
        return grey_image(array if self.distortion is None else undistort_image(array, self.K, self.distortion))


@dataclass
class Sequence:
    """A recording: cameras with equal frame counts (or each with its own stamps and count), optional timestamps (N,)
    in seconds, camera 0's."""

    name: str
    path: Path
    layout: str
    cameras: list[Camera]
    times: np.ndarray | None = None
    pairing: Pairing | None = None  # how the frames were paired, where the cameras had clocks of their own

    def __post_init__(self):
        if not self.cameras:
            raise InputError(f"{self.path}: no cameras")
        first = self.cameras[0]
        for cam in self.cameras[1:]:
            if len(cam) != len(first) and (cam.times is None or first.times is None):
                raise InputError(_count_mismatch(first, cam))
        for cam in self.cameras:
            for what, items in (("poses", cam.poses), ("depth maps", cam.depth), ("timestamps", cam.times)):
                if items is not None and len(items) != len(cam):
                    raise InputError(f"{self.path}: camera {cam.name} has {len(cam)} images but {len(items)} {what}")
        if self.times is not None and len(self.times) != len(first):
            raise InputError(f"{self.path}: {len(self.times)} timestamps for {len(first)} frames")

    def __len__(self) -> int:
        """Camera 0's frame count (every camera's, but for cameras with stamps and counts of their own)."""
        return len(self.cameras[0])

    @property
    def common(self) -> int:
        """The frames every camera has: frame t < common exists in each (each at its own time where they have
        stamps of their own)."""
        return min(len(c) for c in self.cameras)

    @property
    def names(self) -> list[str]:
        return [c.name for c in self.cameras]

    def at(self, frames: np.ndarray) -> Sequence:
        """The sequence at its frames ``frames`` (M,) int, increasing (of every camera: frames paired or triggered
        together), its times and pairing with them."""
        return replace(
            self,
            cameras=[c.at(frames) for c in self.cameras],
            times=None if self.times is None else self.times[frames],
            pairing=None if self.pairing is None else self.pairing.at(frames),
        )

    def camera(self, name: str) -> Camera:
        for cam in self.cameras:
            if cam.name == name:
                return cam
        raise InputError(f"{self.path}: no camera {name!r} (cameras: {', '.join(self.names)})")

    def select(self, names: list[str] | None) -> Sequence:
        """The sequence with only the cameras ``names`` (in that order); extrinsics (and changes) are
        re-referenced to the first of them. ``None`` keeps all. Where the first camera and another change
        at different frames, the other's extrinsic relative to the first changes twice: an :class:`InputError`."""
        if names is None:
            return self
        cameras = [self.camera(n) for n in names]
        ref = cameras[0]
        if ref.T_cam0_cam is not None:
            ref_inv = np.linalg.inv(ref.T_cam0_cam)
            cameras = [replace(ref, T_cam0_cam=ref_inv @ ref.T_cam0_cam, change=None)] + [
                replace(
                    c,
                    T_cam0_cam=None if c.T_cam0_cam is None else ref_inv @ c.T_cam0_cam,
                    change=self._rereferenced_change(c, ref),
                )
                for c in cameras[1:]
            ]
        return replace(self, cameras=cameras)

    def _rereferenced_change(self, cam: Camera, ref: Camera) -> ExtrinsicChange | None:
        """``cam``'s change of extrinsic relative to ``ref`` (None where neither changes or ``cam`` has no extrinsic)."""
        if cam.T_cam0_cam is None or (cam.change is None and ref.change is None):
            return cam.change
        frames = {ch.frame for ch in (cam.change, ref.change) if ch is not None}
        if len(frames) > 1:
            raise InputError(
                f"{self.path}: cameras {ref.name} and {cam.name} move at different frames ({ref.change.frame}, "
                f"{cam.change.frame}): {ref.name} cannot be the extrinsics reference"
            )
        ref_after = ref.T_cam0_cam if ref.change is None else ref.change.T_cam0_cam
        cam_after = cam.T_cam0_cam if cam.change is None else cam.change.T_cam0_cam
        return ExtrinsicChange(frames.pop(), np.linalg.inv(ref_after) @ cam_after)


def _count_mismatch(a: Camera, b: Camera) -> str:
    """Name the first frame one camera has and the other lacks, or the two counts."""
    if a.images and b.images:
        stems_a, stems_b = {p.stem for p in a.images}, {p.stem for p in b.images}
        for cam, other, others in ((b, a, stems_b), (a, b, stems_a)):
            extra = [p for p in other.images if p.stem not in others]
            if extra:
                missing = cam.images[0].with_name(extra[0].stem + cam.images[0].suffix)
                return f"{missing}: frame is missing (camera {other.name} has it; {len(other)} vs {len(cam)} frames)"
    return (
        f"unequal frame counts: {a.images[0].parent if a.images else a.name} has {len(a)} frames, "
        f"{b.images[0].parent if b.images else b.name} has {len(b)}"
    )
