"""The native rig layout's description, ``DIR/rig.yaml``.

```
frame_rate: 10.0
cameras:
  - name: cam0
    width: 416
    height: 128
    K: [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]     # pixels, integer pixel centres
    T_cam0_cam: [[...4 rows of 4...]]            # optional: the true pose of this camera in camera 0's frame
    change: {frame: F, T_cam0_cam: [[...]]}      # optional: the camera was moved; its true pose from frame F on
    distortion: {model: opencv, coeffs: [k1, k2, p1, p2, k3]}   # optional, or {model: fisheye, coeffs: [k1..k4]}
    time_offset: 0.7                             # optional: the true clock offset of this camera, seconds
```

Convention: ``T_cam0_cam`` maps points of this camera into camera 0 (``p_cam0 = R p_cam + t``); it is
the identity for camera 0. A camera's pose in the world is camera 0's pose times ``T_cam0_cam``. It is the
ground truth of a calibration, known for rendered or surveyed rigs only: a camera without it has none (None),
and nothing is compared against it. Where another camera has one, camera 0's may be left out (the identity).
``change`` records a camera knocked out of place mid-sequence: ``T_cam0_cam`` holds for frames ``0 .. F-1``
and the change's ``T_cam0_cam`` for frames ``F ..``; it needs the camera's ``T_cam0_cam``, ``F >= 1``, and
camera 0 (the rig frame) cannot have one. ``distortion`` is the lens's (:mod:`ocalib.data.distortion`, OpenCV's
models); K is then the intrinsics of the distorted images, and of their undistorted view; none is a pinhole.
``time_offset`` is the truth of a camera on a clock of its own (``DIR/<name>/times.txt``): the seconds added to its
stamps to put them on camera 0's clock, ``t0 = tk + time_offset``; known for rendered rigs only.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from ocalib.data.distortion import Distortion, read_distortion
from ocalib.errors import InputError, read_text


@dataclass(frozen=True)
class ExtrinsicChange:
    """A camera moved on the rig: its true ``T_cam0_cam`` (4, 4) float64 from frame ``frame`` (>= 1) on."""

    frame: int
    T_cam0_cam: np.ndarray


@dataclass
class CameraSpec:
    name: str
    width: int
    height: int
    K: np.ndarray  # (3, 3) float64, pixels
    T_cam0_cam: np.ndarray | None = None  # (4, 4) float64, the true extrinsic where known (at frame 0)
    change: ExtrinsicChange | None = None  # the true extrinsic from a later frame on, where the camera moved
    distortion: Distortion | None = None  # the lens's, None for a pinhole
    time_offset: float | None = None  # seconds, the true t0 - tk of a camera on its own clock, where known


@dataclass
class RigSpec:
    cameras: list[CameraSpec]
    frame_rate: float = 10.0

    def camera(self, name: str) -> CameraSpec:
        for cam in self.cameras:
            if cam.name == name:
                return cam
        raise InputError(f"no camera named {name!r} in the rig (cameras: {', '.join(c.name for c in self.cameras)})")


def write_rig_yaml(path: str | Path, rig: RigSpec) -> None:
    data = {
        "frame_rate": float(rig.frame_rate),
        "cameras": [
            {
                "name": c.name,
                "width": int(c.width),
                "height": int(c.height),
                "K": np.asarray(c.K, dtype=float).tolist(),
            }
            | ({} if c.T_cam0_cam is None else {"T_cam0_cam": np.asarray(c.T_cam0_cam, dtype=float).tolist()})
            | ({} if c.change is None else {"change": _change_dict(c.change)})
            | ({} if c.distortion is None else {"distortion": c.distortion.as_dict()})
            | ({} if c.time_offset is None else {"time_offset": float(c.time_offset)})
            for c in rig.cameras
        ],
    }
    Path(path).write_text(yaml.safe_dump(data, sort_keys=False, default_flow_style=None))


def _change_dict(change: ExtrinsicChange) -> dict:
    return {"frame": int(change.frame), "T_cam0_cam": np.asarray(change.T_cam0_cam, dtype=float).tolist()}


def _read_change(data, first: bool, has_T: bool, where: str) -> ExtrinsicChange:
    """The ``change`` entry ``{frame, T_cam0_cam}`` of a camera; :class:`InputError` naming ``where`` otherwise."""
    if first:
        raise InputError(f"{where}: change: camera 0 defines the rig frame and cannot change")
    if not has_T:
        raise InputError(f"{where}: change needs the camera's T_cam0_cam (its extrinsic before the change)")
    if not isinstance(data, dict) or set(data) != {"frame", "T_cam0_cam"}:
        got = f"keys {sorted(map(str, data))}" if isinstance(data, dict) else f"a {type(data).__name__}"
        raise InputError(f"{where}: change must be a mapping with exactly frame and T_cam0_cam, got {got}")
    frame = data["frame"]
    if not isinstance(frame, int) or isinstance(frame, bool) or frame < 1:
        raise InputError(f"{where}: change.frame must be an integer >= 1, got {frame!r}")
    try:
        T = np.asarray(data["T_cam0_cam"], dtype=np.float64)
    except (TypeError, ValueError):
        T = None
    if T is None or T.shape != (4, 4) or not np.isfinite(T).all():
        raise InputError(f"{where}: change.T_cam0_cam must be 4x4, all finite")
    return ExtrinsicChange(frame, T)


def _read_time_offset(value, where: str) -> float | None:
    """A camera's ``time_offset`` entry: None, or finite seconds; :class:`InputError` naming ``where`` otherwise."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        raise InputError(f"{where}: time_offset must be a finite number of seconds, got {value!r}")
    return float(value)


def read_rig_yaml(path: str | Path) -> RigSpec:
    """Read ``rig.yaml``; every problem is an :class:`InputError` naming the file and field."""
    path = Path(path)
    try:
        data = yaml.safe_load(read_text(path, "rig description (rig.yaml)"))
    except yaml.YAMLError as err:
        raise InputError(f"{path}: not valid YAML ({err})") from None
    if not isinstance(data, dict) or not isinstance(data.get("cameras"), list) or not data["cameras"]:
        raise InputError(f"{path}: expected a mapping with a non-empty 'cameras' list")
    cameras = []
    for i, c in enumerate(data["cameras"]):
        where = f"{path}: cameras[{i}]"
        try:
            K = np.asarray(c["K"], dtype=np.float64)
            T = None if c.get("T_cam0_cam") is None else np.asarray(c["T_cam0_cam"], dtype=np.float64)
            cam = CameraSpec(str(c["name"]), int(c["width"]), int(c["height"]), K, T)
        except (AttributeError, KeyError, TypeError, ValueError) as err:
            raise InputError(f"{where}: missing or malformed field ({err})") from None
        if K.shape != (3, 3) or not np.isfinite(K).all():
            raise InputError(f"{where}: K must be 3x3, all finite")
        if T is not None and (T.shape != (4, 4) or not np.isfinite(T).all()):
            raise InputError(f"{where}: T_cam0_cam must be 4x4, all finite")
        if c.get("change") is not None:
            cam.change = _read_change(c["change"], i == 0, T is not None, f"{where} ({cam.name})")
        cam.distortion = read_distortion(c.get("distortion"), f"{where} ({cam.name})")
        cam.time_offset = _read_time_offset(c.get("time_offset"), f"{where} ({cam.name})")
        cameras.append(cam)
    if cameras[0].T_cam0_cam is None and any(c.T_cam0_cam is not None for c in cameras[1:]):
        cameras[0].T_cam0_cam = np.eye(4)
    return RigSpec(cameras, float(data.get("frame_rate", 10.0)))
