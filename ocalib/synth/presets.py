"""The built-in presets (mirrored by ``configs/synth/<name>.yaml``; a test keeps them equal).

All cameras default to KITTI-like normalised intrinsics (``fx = 0.58 W``, ``fy = 1.92 H``, ~80x29 deg).
"""

from __future__ import annotations

import copy
import dataclasses

from ocalib.errors import InputError
from ocalib.synth.config import SynthConfig, config_from_dict

PRESETS: dict[str, dict] = {
    "front-rear": {
        "name": "front-rear",
        "trajectory": {"kind": "drive", "speed": 8.0, "height": 1.65},
        "cameras": [
            {"name": "front"},
            {"name": "rear", "position": [0.0, 0.1, -2.2], "rotation_deg": [0.0, 180.0, 0.0]},
        ],
    },
    "front-left": {
        "name": "front-left",
        "trajectory": {"kind": "drive", "speed": 8.0, "height": 1.65},
        "cameras": [
            {"name": "front"},
            {"name": "left", "position": [-0.9, 0.3, -1.0], "rotation_deg": [0.0, -100.0, 0.0]},
        ],
    },
    "handheld": {
        "name": "handheld",
        "trajectory": {"kind": "handheld", "speed": 1.4, "height": 1.5},
        "cameras": [
            {"name": "cam0", "fx": 0.5, "fy": 1.6},
            {"name": "cam1", "fx": 0.5, "fy": 1.6, "position": [0.12, 0.0, -0.05], "rotation_deg": [0.0, 120.0, 0.0]},
        ],
    },
    "surround": {
        "name": "surround",
        "trajectory": {"kind": "drive", "speed": 8.0, "height": 1.65},
        "cameras": [
            {"name": "front"},
            {"name": "left", "position": [-0.9, 0.3, -1.0], "rotation_deg": [0.0, -90.0, 0.0]},
            {"name": "right", "position": [0.9, 0.3, -1.0], "rotation_deg": [0.0, 90.0, 0.0]},
            {"name": "rear", "position": [0.0, 0.1, -3.2], "rotation_deg": [0.0, 180.0, 0.0]},
        ],
    },
    "stereo": {
        "name": "stereo",
        "trajectory": {"kind": "drive", "speed": 8.0, "height": 1.65},
        "cameras": [
            {"name": "left"},
            {"name": "right", "position": [0.54, 0.0, 0.0]},
        ],
    },
}


def preset(name: str) -> SynthConfig:
    """The validated :class:`SynthConfig` of a built-in preset."""
    if name not in PRESETS:
        raise InputError(f"unknown preset {name!r} (presets: {', '.join(PRESETS)})")
    return config_from_dict(copy.deepcopy(PRESETS[name]), f"preset {name}")


def knocked(cfg: SynthConfig, frame: int) -> SynthConfig:
    """``cfg`` with camera 1 knocked from ``frame`` on: turned by 2 deg about its y axis, and on a drive (the cars,
    whose lever arms are metres) also moved 5 cm along camera 0's x axis."""
    cam = cfg.cameras[1]
    shift = [0.05, 0.0, 0.0] if cfg.trajectory["kind"] == "drive" else [0.0, 0.0, 0.0]
    change = {
        "frame": frame,
        "rotation_deg": [cam.rotation_deg[0], cam.rotation_deg[1] + 2.0, cam.rotation_deg[2]],
        "position": [p + d for p, d in zip(cam.position, shift)],
    }
    return cfg.with_overrides(cameras=[cfg.cameras[0], dataclasses.replace(cam, change=change), *cfg.cameras[2:]])
