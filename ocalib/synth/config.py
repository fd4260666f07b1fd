"""What a synthetic sequence is made of: a rig of cameras, a trajectory, a size, a seed.

A config is a small YAML mapping (see ``configs/synth/*.yaml``); every problem is an
:class:`~ocalib.errors.InputError` naming the file and the field.

Intrinsics are given normalised by the image size (``fx`` as a fraction of the width, ``fy`` of the
height, ``cx``/``cy`` as fractions), so a preset renders at any ``--height/--width``.
Convention: pixel centres are integer, so ``K = [[fx W, 0, cx W - 0.5], [0, fy H, cy H - 0.5], [0, 0, 1]]``.

Extrinsics: ``position`` (metres) and ``rotation_deg: [rx, ry, rz]`` of the camera in camera 0's
frame (x right, y down, z forward), ``R = Rz(rz) Ry(ry) Rx(rx)``: ``ry = -90`` looks left, ``90`` right,
``180`` backwards; ``rx > 0`` looks down. Camera 0 must have the identity.

A camera other than camera 0 may be knocked out of place mid-sequence: ``change: {frame: F, rotation_deg:
[rx, ry, rz], position: [x, y, z]}`` is its new mounting (absolute, same convention) from frame F on,
``1 <= F <= frames - 1``.

A camera may have a lens: ``distortion: {model: opencv, coeffs: [k1, k2, p1, p2, k3]}`` or ``{model: fisheye,
coeffs: [k1, k2, k3, k4]}`` (OpenCV's models, :mod:`ocalib.data.distortion`); it is rendered exactly (a ray per
pixel) and written into rig.yaml. It must be invertible over the image (no ray folding back).

A camera other than camera 0 may capture late, on a clock of its own: ``time_offset: S`` (seconds, ``0 <= S <=
MAX_TIME_OFFSET``) renders its frame i at ``i / frame_rate + S`` on camera 0's clock, while its own ``times.txt``
says ``i / frame_rate``; the truth ``t0 = tk + S`` is written into rig.yaml.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from ocalib.data.distortion import Distortion, invertible, read_distortion
from ocalib.errors import InputError, read_text

TRAJECTORIES = ("drive", "handheld", "lds")  # see ocalib.synth.trajectory; options: speed (m/s), height (m)
CHANGE_KEYS = ("frame", "rotation_deg", "position")
MAX_TIME_OFFSET = 2.0  # seconds: the route rendered has room for the rig to drive on this long


def mounting(rotation_deg, position) -> np.ndarray:
    """(4, 4) float64 pose of a camera in camera 0's frame: ``R = Rz(rz) Ry(ry) Rx(rx)``, ``t = position``."""
    rx, ry, rz = np.radians(rotation_deg)
    cx, sx, cy, sy, cz, sz = math.cos(rx), math.sin(rx), math.cos(ry), math.sin(ry), math.cos(rz), math.sin(rz)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    T = np.eye(4)
    T[:3, :3] = Rz @ Ry @ Rx
    T[:3, 3] = position
    return T


@dataclass
class CameraConfig:
    name: str
    fx: float = 0.58
    fy: float = 1.92
    cx: float = 0.5
    cy: float = 0.5
    position: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    rotation_deg: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    change: dict | None = None  # {frame: F, rotation_deg: [3], position: [3]}: the mounting from frame F on
    distortion: Distortion | None = None  # the lens's ({model, coeffs} in a config), None for a pinhole
    time_offset: float = 0.0  # seconds this camera captures late: its frame i at i / frame_rate + time_offset

    def K(self, height: int, width: int) -> np.ndarray:
        """(3, 3) float64 pixel intrinsics at this size (integer pixel centres)."""
        return np.array(
            [[self.fx * width, 0, self.cx * width - 0.5], [0, self.fy * height, self.cy * height - 0.5], [0, 0, 1]]
        )

    def T_cam0_cam(self, frame: int = 0) -> np.ndarray:
        """(4, 4) float64 pose of this camera in camera 0's frame at ``frame`` (the ``change`` from its frame on)."""
        if self.change is not None and frame >= self.change["frame"]:
            return mounting(self.change["rotation_deg"], self.change["position"])
        return mounting(self.rotation_deg, self.position)

    def extrinsics(self, frames: int) -> np.ndarray:
        """(frames, 4, 4) float64 ``T_cam0_cam`` in force at each frame 0 .. frames - 1."""
        T = np.repeat(self.T_cam0_cam()[None], frames, axis=0)
        if self.change is not None:
            T[self.change["frame"] :] = self.T_cam0_cam(self.change["frame"])
        return T


@dataclass
class SynthConfig:
    """One synthetic sequence. ``trajectory`` holds ``kind`` (drive | handheld | lds) and its options."""

    name: str
    cameras: list[CameraConfig]
    trajectory: dict = field(default_factory=lambda: {"kind": "drive"})
    frames: int = 300
    seed: int = 0
    frame_rate: float = 10.0
    height: int = 128
    width: int = 416
    supersample: int = 2
    photometric: bool = False

    def with_overrides(self, **kw) -> SynthConfig:
        """A copy with the given fields replaced (``None`` values are ignored), validated; errors name the
        overrides as the command line gives them (``front-rear with --frames 0``)."""
        cfg = dataclasses.replace(self, **{k: v for k, v in kw.items() if v is not None})
        return validate(cfg, overridden(self.name, kw))

    def to_dict(self) -> dict:
        """As a config file holds it (:func:`config_from_dict` reads it back)."""
        out = dataclasses.asdict(self)
        for cam, c in zip(out["cameras"], self.cameras):
            cam["distortion"] = None if c.distortion is None else c.distortion.as_dict()
        return out


def validate(cfg: SynthConfig, where: str = "config") -> SynthConfig:
    """Check sizes and values; raise :class:`InputError` naming ``where`` and the field."""
    checks = [
        ("frames", cfg.frames, cfg.frames >= 1),
        ("height", cfg.height, 8 <= cfg.height <= 4096),
        ("width", cfg.width, 8 <= cfg.width <= 4096),
        ("supersample", cfg.supersample, cfg.supersample in (1, 2, 3, 4)),
        ("frame_rate", cfg.frame_rate, cfg.frame_rate > 0),
    ]
    for name, value, ok in checks:
        if not ok:
            raise InputError(f"{where}: bad {name}: {value!r}")
    if not cfg.cameras:
        raise InputError(f"{where}: needs at least one camera")
    names = [c.name for c in cfg.cameras]
    if len(set(names)) != len(names) or not all(n and "/" not in n for n in names):
        raise InputError(f"{where}: camera names must be unique folder names, got {names}")
    for c in cfg.cameras:
        if len(c.position) != 3 or len(c.rotation_deg) != 3:
            raise InputError(f"{where}: camera {c.name}: position and rotation_deg need 3 numbers each")
        if min(c.fx, c.fy) <= 0 or not all(map(math.isfinite, [c.fx, c.fy, c.cx, c.cy, *c.position, *c.rotation_deg])):
            raise InputError(f"{where}: camera {c.name}: fx, fy must be > 0 and all numbers finite")
    for c in cfg.cameras:
        _check_distortion(c, cfg.height, cfg.width, where)
    c0 = cfg.cameras[0]
    if any(c0.position) or any(c0.rotation_deg):
        raise InputError(f"{where}: camera 0 ({c0.name}) defines the rig frame: its position and rotation must be 0")
    if c0.change is not None:
        raise InputError(f"{where}: camera 0 ({c0.name}) defines the rig frame: it cannot have a change")
    if c0.time_offset != 0:
        raise InputError(f"{where}: camera 0 ({c0.name}) defines the clock: its time_offset must be 0")
    for c in cfg.cameras[1:]:
        if not (_is_number(c.time_offset) and 0 <= c.time_offset <= MAX_TIME_OFFSET):
            raise InputError(
                f"{where}: camera {c.name}: time_offset must be seconds in [0, {MAX_TIME_OFFSET}], got {c.time_offset!r}"
            )
    for c in cfg.cameras[1:]:
        if c.change is not None:
            _check_change(c, cfg.frames, where)
    traj = cfg.trajectory
    if traj.get("kind") not in TRAJECTORIES:
        raise InputError(f"{where}: trajectory.kind must be one of {', '.join(TRAJECTORIES)}")
    unknown = set(traj) - {"kind", "speed", "height"}
    if unknown:
        raise InputError(
            f"{where}: trajectory: unknown option(s) {', '.join(sorted(unknown))} (options: speed, height)"
        )
    for name, lo, hi in (("speed", 0.0, 40.0), ("height", 0.5, 3.0)):
        value = traj.get(name, lo + 1e-9)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (lo < value <= hi):
            raise InputError(f"{where}: trajectory.{name} must be a number in ({lo}, {hi}], got {value!r}")
    return cfg


def _is_number(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)


def _check_distortion(c: CameraConfig, height: int, width: int, where: str) -> None:
    """Parse ``c.distortion`` into a :class:`Distortion` in place; :class:`InputError` where it is malformed or
    not invertible over the image."""
    where = f"{where}: camera {c.name}"
    c.distortion = read_distortion(c.distortion, where)
    if c.distortion is not None and not invertible(c.K(height, width), (height, width), c.distortion):
        raise InputError(
            f"{where}: distortion {c.distortion.as_dict()} folds back inside the {height}x{width} image "
            "(some pixels have no ray); use weaker coefficients"
        )


def _check_change(c: CameraConfig, frames: int, where: str) -> None:
    """Raise :class:`InputError` unless ``c.change`` is ``{frame: int in [1, frames-1], rotation_deg: [3], position: [3]}``."""
    where = f"{where}: camera {c.name}: change"
    change = c.change
    if not isinstance(change, dict):
        raise InputError(f"{where}: expected a mapping {{frame, rotation_deg, position}}, got {change!r}")
    unknown = set(change) - set(CHANGE_KEYS)
    if unknown:
        raise InputError(
            f"{where}: unknown key(s) {', '.join(sorted(map(str, unknown)))} (keys: {', '.join(CHANGE_KEYS)})"
        )
    missing = [k for k in CHANGE_KEYS if k not in change]
    if missing:
        raise InputError(f"{where}: missing {', '.join(missing)} (needs {', '.join(CHANGE_KEYS)})")
    frame = change["frame"]
    if not isinstance(frame, numbers.Integral) or isinstance(frame, bool) or not 1 <= frame <= frames - 1:
        raise InputError(f"{where}: frame must be an integer in [1, {frames - 1}] (frames: {frames}), got {frame!r}")
    for key in ("rotation_deg", "position"):
        value = change[key]
        if not isinstance(value, (list, tuple)) or len(value) != 3 or not all(map(_is_number, value)):
            raise InputError(f"{where}: {key} needs 3 finite numbers, got {value!r}")


def config_from_dict(data, where: str = "config") -> SynthConfig:
    """Build and validate a :class:`SynthConfig` from a plain mapping (e.g. parsed YAML)."""
    if not isinstance(data, dict):
        raise InputError(f"{where}: expected a mapping of config fields")
    known = {f.name for f in dataclasses.fields(SynthConfig)}
    unknown = set(data) - known
    if unknown:
        raise InputError(f"{where}: unknown field(s) {', '.join(sorted(unknown))} (known: {', '.join(sorted(known))})")
    if "name" not in data or "cameras" not in data:
        raise InputError(f"{where}: needs 'name' and 'cameras'")
    if not isinstance(data["cameras"], list):
        raise InputError(f"{where}: 'cameras' must be a list")
    try:
        cameras = [CameraConfig(**c) for c in data["cameras"]]
        kw = {k: v for k, v in data.items() if k != "cameras"}
        cfg = SynthConfig(cameras=cameras, **kw)
        for name, kind in [("frames", int), ("seed", int), ("height", int), ("width", int), ("supersample", int)]:
            if not isinstance(getattr(cfg, name), kind) or isinstance(getattr(cfg, name), bool):
                raise TypeError(f"{name} must be an integer")
        cfg.frame_rate = float(cfg.frame_rate)
        for c in cameras:
            c.name = str(c.name)
            c.fx, c.fy, c.cx, c.cy = (float(v) for v in (c.fx, c.fy, c.cx, c.cy))
            c.position = [float(v) for v in c.position]
            c.rotation_deg = [float(v) for v in c.rotation_deg]
            c.time_offset = float(c.time_offset)
        if not isinstance(cfg.trajectory, dict):
            raise TypeError("trajectory must be a mapping")
    except (TypeError, ValueError) as err:
        raise InputError(f"{where}: malformed field ({err})") from None
    validate(cfg, where)
    for c in cameras:
        if c.change is not None:
            c.change = {
                "frame": int(c.change["frame"]),
                "rotation_deg": [float(v) for v in c.change["rotation_deg"]],
                "position": [float(v) for v in c.change["position"]],
            }
    return cfg


def overridden(where: str, overrides: dict) -> str:
    """``where`` and the ``overrides`` given (not None) as ``ocalib synth`` options: ``cfg.yaml with --frames 100``."""
    given = [f"--{k}" if v is True else f"--{k} {v}" for k, v in overrides.items() if v is not None]
    return f"{where} with {' '.join(given)}" if given else where


def load_config(path: str | Path, **overrides) -> SynthConfig:
    """Read a YAML config file with fields replaced by ``overrides`` (``None`` values are ignored) before it is
    checked, so that its checks see the values that will render (errors name the file and the overrides)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such config file")
    try:
        data = yaml.safe_load(read_text(path, "YAML config"))
    except yaml.YAMLError as err:
        raise InputError(f"{path}: not valid YAML ({str(err).splitlines()[0]})") from None
    if isinstance(data, dict):
        data = data | {k: v for k, v in overrides.items() if v is not None}
    return config_from_dict(data, overridden(str(path), overrides))
