"""A COLMAP workspace of a rig sequence: its images under one folder, one database with every camera's features,
the rig and its frames, and the verified matches. Frames can be added as a stream arrives: only the new images
are read and matched.

Image ``t`` of camera ``k`` is ``c{k}/{t:06d}{suffix}`` (a link to the sequence's file), so COLMAP groups the images
of one instant into one rig frame by their common name. Camera 0 is the rig's reference sensor.

Convention: intrinsics K (3, 3) in ocalib's pixels (integer centres) and each camera's lens, converted by
:func:`ocalib.rigba.colmap.colmap_camera` (held fixed: COLMAP reads the original, distorted images);
``extrinsics`` (C, 4, 4) are ``T_cam0_camk`` (``p_cam0 = R p_camk + t``), the identity for camera 0.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pycolmap

from ocalib.data.sequence import Sequence
from ocalib.errors import InputError
from ocalib.rigba.colmap import colmap_camera, to_rigid
from ocalib.rigba.options import FeatureOptions


@dataclass
class Workspace:
    """A workspace under ``root``: ``images`` (the linked frames), ``database``; ``frames`` the sequence frame indices
    it holds, ``camera_ids`` COLMAP's camera id of each camera, ``seconds`` time spent per step."""

    root: Path
    sequence: Sequence
    extrinsics: np.ndarray
    options: FeatureOptions = FeatureOptions()
    frames: list[int] = field(default_factory=list)
    camera_ids: list[int] = field(default_factory=list)
    seconds: dict = field(default_factory=lambda: {"features": 0.0, "matching": 0.0})

    @property
    def images(self) -> Path:
        return self.root / "images"

    @property
    def database(self) -> Path:
        return self.root / "database.db"

    def add_frames(self, frames: list[int]) -> None:
        """Link, extract and match the sequence's ``frames`` (new ones, in increasing order) of every camera."""
        frames = [t for t in frames if not self.frames or t > self.frames[-1]]
        if not frames:
            return
        start = time.perf_counter()
        names = self._link(frames)
        extraction = pycolmap.FeatureExtractionOptions(num_threads=self.options.threads)
        extraction.sift.max_num_features = self.options.max_features
        extraction.sift.peak_threshold = self.options.peak_threshold
        for k, cam in enumerate(self.sequence.cameras):
            camera = colmap_camera(cam.K, cam.size, cam.distortion, k + 1)
            reader = pycolmap.ImageReaderOptions(
                camera_model=camera.model.name, camera_params=",".join(f"{v:.17g}" for v in camera.params)
            )
            if self.camera_ids:
                reader.existing_camera_id = self.camera_ids[k]
            pycolmap.extract_features(
                self.database,
                self.images,
                image_names=names[k],
                camera_mode=pycolmap.CameraMode.SINGLE,
                reader_options=reader,
                extraction_options=extraction,
                device=pycolmap.Device.cpu,
            )
        self.frames += frames
        self._configure_rig()
        self.seconds["features"] += time.perf_counter() - start
        start = time.perf_counter()
        pairing = pycolmap.SequentialPairingOptions(
            overlap=self.options.overlap, expand_rig_images=self.options.cross_camera, num_threads=self.options.threads
        )
        pycolmap.match_sequential(
            self.database,
            matching_options=pycolmap.FeatureMatchingOptions(num_threads=self.options.threads),
            pairing_options=pairing,
            device=pycolmap.Device.cpu,
        )
        self.seconds["matching"] += time.perf_counter() - start

    def _link(self, frames: list[int]) -> list[list[str]]:
        """Symbolic links ``images/c{k}/{t:06d}{suffix}`` to the sequence's files -> the names, per camera."""
        names = []
        for k, cam in enumerate(self.sequence.cameras):
            (self.images / f"c{k}").mkdir(parents=True, exist_ok=True)
            names.append([])
            for t in frames:
                source = Path(cam.images[t]).resolve()
                name = f"c{k}/{t:06d}{source.suffix.lower()}"
                os.symlink(source, self.images / name)
                names[-1].append(name)
        return names

    def _configure_rig(self) -> None:
        """One rig of every camera, camera 0 its reference, camera k at ``inverse(extrinsics[k])`` from the rig; the
        images of one frame index form one rig frame."""
        rig_cameras = [pycolmap.RigConfigCamera(ref_sensor=True, image_prefix="c0/")]
        for k in range(1, len(self.sequence.cameras)):
            rig_cameras.append(
                pycolmap.RigConfigCamera(
                    image_prefix=f"c{k}/", cam_from_rig=to_rigid(np.linalg.inv(self.extrinsics[k]))
                )
            )
        database = pycolmap.Database.open(self.database)
        try:
            pycolmap.apply_rig_config([pycolmap.RigConfig(cameras=rig_cameras)], database)
            if not self.camera_ids:
                ids = {camera_and_frame(im.name)[0]: im.camera_id for im in database.read_all_images()}
                self.camera_ids = [ids[k] for k in range(len(self.sequence.cameras))]
        finally:
            database.close()


def camera_and_frame(name: str) -> tuple[int, int]:
    """``(k, t)`` of a workspace image named ``c{k}/{t:06d}{suffix}``."""
    camera, file = name.split("/")
    return int(camera[1:]), int(Path(file).stem)


def create_workspace(
    root: str | Path, sequence: Sequence, extrinsics: np.ndarray, options: FeatureOptions = FeatureOptions()
) -> Workspace:
    """An empty workspace under ``root`` (which must not hold one) for ``sequence``'s cameras, camera k's
    ``sensor_from_rig`` started from ``extrinsics[k]`` (C, 4, 4)."""
    ws = Workspace(Path(root), sequence, np.asarray(extrinsics, dtype=np.float64), options)
    if ws.database.exists():
        raise InputError(f"{ws.database}: a workspace is already there")
    ws.root.mkdir(parents=True, exist_ok=True)
    return ws
