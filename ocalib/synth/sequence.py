"""Render a whole synthetic rig sequence, in memory or to the native layout on disk.

Convention: camera 0's poses come from the trajectory; every camera's world pose at frame t is computed as
``pose_cam0[t] @ T_cam0_cam(t)`` in float64 (the extrinsic in force at t: the rig is exactly rigid, except
where a camera's ``change`` moves it). Poses are camera-to-world.
"""

from __future__ import annotations

import contextlib
import shutil
import signal
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ocalib.data.rig import CameraSpec, ExtrinsicChange, RigSpec
from ocalib.errors import InputError
from ocalib.synth.config import SynthConfig
from ocalib.synth.photometric import Photometric
from ocalib.synth.render import FAR, WorldTensors, render_view
from ocalib.synth.trajectory import trajectory
from ocalib.synth.world import World, make_world
from ocalib.synth.writer import write_frame, write_header


@dataclass
class SynthSequence:
    """An in-memory sequence of K cameras and N frames.

    images (K, N, 3, H, W) float32 in [0, 1]; depth (K, N, H, W) float32 metres (0 = sky);
    poses (K, N, 4, 4) float64 camera-to-world; times (N,) seconds; rig (intrinsics, extrinsics).
    """

    images: Tensor
    depth: Tensor
    poses: Tensor
    times: Tensor
    rig: RigSpec


def rig_spec(cfg: SynthConfig) -> RigSpec:
    """The rig.yaml description of a config at its resolution (``T_cam0_cam`` at frame 0, any change and lens)."""
    cams = [
        CameraSpec(
            c.name,
            cfg.width,
            cfg.height,
            c.K(cfg.height, cfg.width),
            c.T_cam0_cam(),
            None if c.change is None else ExtrinsicChange(c.change["frame"], c.T_cam0_cam(c.change["frame"])),
            c.distortion,
            c.time_offset if any(d.time_offset for d in cfg.cameras) else None,
        )
        for c in cfg.cameras
    ]
    return RigSpec(cams, cfg.frame_rate)


def camera_poses(cfg: SynthConfig) -> np.ndarray:
    """World poses (K, N, 4, 4) float64 of every camera: ``pose_cam0[t] @ T_cam0_cam(t)``, camera 0's pose taken at
    the camera's own capture time (its ``time_offset`` late)."""
    opts = {k: v for k, v in cfg.trajectory.items() if k != "kind"}
    unknown = set(opts) - {"speed", "height"}
    if unknown:
        raise InputError(f"trajectory: unknown option(s) {', '.join(sorted(unknown))} (options: speed, height)")
    frames = np.arange(cfg.frames)
    kind = cfg.trajectory["kind"]
    return np.stack(
        [
            trajectory(kind, cfg.frames, cfg.frame_rate, cfg.seed, **opts, at=frames + c.time_offset * cfg.frame_rate)
            @ c.extrinsics(cfg.frames)
            for c in cfg.cameras
        ]
    )


def world_for(cfg: SynthConfig, poses: np.ndarray) -> World:
    """The city around all camera positions, out to the render distance."""
    xy = poses[..., :2, 3].reshape(-1, 2)
    return make_world(cfg.seed, xy.min(0) - FAR - 5, xy.max(0) + FAR + 5)


def frames(cfg: SynthConfig, device="cpu", progress: bool = False, indices=None):
    """Yield ``(index, [(image (3, H, W), depth (H, W)) per camera])`` for every frame (or ``indices``)."""
    poses = camera_poses(cfg)
    world = WorldTensors.from_world(world_for(cfg, poses), device)
    photometric = Photometric(cfg.seed, len(cfg.cameras)) if cfg.photometric else None
    Ks = [c.K(cfg.height, cfg.width) for c in cfg.cameras]
    indices = range(cfg.frames) if indices is None else indices
    if progress:
        from tqdm import tqdm

        indices = tqdm(indices, desc=f"synth {cfg.name}", unit="frame")
    for n in indices:
        views = []
        for k, K in enumerate(Ks):
            lens = cfg.cameras[k].distortion
            image, depth = render_view(world, K, poses[k, n], cfg.height, cfg.width, cfg.supersample, lens)
            if photometric is not None:
                image = photometric.apply(image, k, n)
            views.append((image, depth))
        yield n, views


def render_rig(cfg: SynthConfig, device="cpu", progress: bool = False) -> SynthSequence:
    """Render a sequence in memory (for tests and small experiments)."""
    images, depths = [], []
    for _, views in frames(cfg, device, progress):
        images.append(torch.stack([v[0] for v in views]))
        depths.append(torch.stack([v[1] for v in views]))
    poses = torch.from_numpy(camera_poses(cfg))
    times = torch.arange(cfg.frames, dtype=torch.float64) / cfg.frame_rate
    return SynthSequence(torch.stack(images, 1).cpu(), torch.stack(depths, 1).cpu(), poses, times, rig_spec(cfg))


def _ignore_interrupt() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)


@contextlib.contextmanager
def _interrupt_ignored():
    """SIGINT ignored inside (in the main thread; elsewhere Python's handler is not this thread's to change)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _write_frames(job) -> int:
    """Worker: render and write frames ``indices`` of ``cfg`` with one torch thread; returns the count."""
    cfg, out, device, indices = job
    torch.set_num_threads(1)
    with torch.inference_mode():
        for n, views in frames(cfg, device, indices=indices):
            for c, (image, depth) in zip(cfg.cameras, views):
                write_frame(out, c.name, n, image, depth)
    return len(indices)


def render_sequence(
    cfg: SynthConfig, out_dir, device="cpu", progress: bool = True, overwrite: bool = False, workers: int = 1
) -> Path:
    """Render a sequence and write the native rig layout to ``out_dir``; returns the folder.

    ``workers > 1`` renders frames in that many processes (CPU, one torch thread each: robust on a busy
    machine, where intra-op threads can spin). The output does not depend on ``workers``.
    A non-empty ``out_dir`` is an :class:`InputError` unless ``overwrite``, which replaces rig.yaml,
    times.txt and the camera folders of this config (nothing else is touched).
    """
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder")
    if out.is_dir() and any(out.iterdir()):
        if not overwrite:
            raise InputError(f"{out}: folder is not empty (pass --overwrite to replace a rendered sequence)")
        for name in ["rig.yaml", "times.txt"]:
            (out / name).unlink(missing_ok=True)
        for c in cfg.cameras:
            shutil.rmtree(out / c.name, ignore_errors=True)
    if workers < 1:
        raise InputError(f"workers must be >= 1, got {workers}")
    times = np.arange(cfg.frames) / cfg.frame_rate
    write_header(out, rig_spec(cfg), times, camera_poses(cfg))
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=cfg.frames, desc=f"synth {cfg.name}", unit="frame")
    if workers == 1 or str(device).startswith("cuda"):
        with torch.inference_mode():
            for n, views in frames(cfg, device):
                for c, (image, depth) in zip(cfg.cameras, views):
                    write_frame(out, c.name, n, image, depth)
                if bar is not None:
                    bar.update(1)
    else:
        import multiprocessing

        chunk = max(8, -(-cfg.frames // (4 * workers)))  # each job builds the world once (~0.1 s)
        jobs = [(cfg, out, device, list(range(i, min(i + chunk, cfg.frames)))) for i in range(0, cfg.frames, chunk)]
        # Ctrl-C reaches the whole process group: the workers ignore it (from their start: they inherit the
        # ignored signal) and the main process stops them
        with _interrupt_ignored():
            pool = multiprocessing.get_context("spawn").Pool(workers, initializer=_ignore_interrupt)
        with pool:
            for done in pool.imap_unordered(_write_frames, jobs):
                if bar is not None:
                    bar.update(done)
    if bar is not None:
        bar.close()
    return out
