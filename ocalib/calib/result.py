"""The calibration estimate of one frame, as tensors, and its JSON form."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import torch
from torch import Tensor


@dataclass
class Calibration:
    """Extrinsics of cameras 1..K against camera 0 for B rigs, with their observability.

    Convention: ``rotation``/``translation`` form ``T_cam0_camk``, the pose of camera k in camera 0's
    frame (``p_cam0 = R p_camk + t``); ``scale`` multiplies camera-k trajectory units into camera-0
    units; quaternions are (w, x, y, z), w >= 0. Shapes lead with (B, K).
    """

    rotation: Tensor  # (B, K, 3, 3)
    quaternion: Tensor  # (B, K, 4)
    translation: Tensor  # (B, K, 3)
    scale: Tensor  # (B, K)
    rotation_singular_values: Tensor  # (B, K, 4), descending
    rotation_observable: Tensor  # (B, K) bool
    planar_motion: Tensor  # (B, K) bool
    translation_information: Tensor  # (B, K, 3) ascending, information on dT with s free
    translation_directions: Tensor  # (B, K, 3, 3) its eigenvectors (columns), camera 0's frame
    translation_unobservable: Tensor  # (B, K, 3) bool, per direction
    rotation_std: Tensor  # (B, K, 3) radians, about camera k's axes
    translation_std: Tensor  # (B, K, 3) camera-0 units along camera 0's axes; inf if unobservable
    scale_std: Tensor  # (B, K)
    frames_used: Tensor  # (B, K) long
    frames_rejected: Tensor  # (B, K) long

    def detach(self) -> Calibration:
        return Calibration(**{f.name: getattr(self, f.name).detach() for f in fields(self)})

    def camera_json(self, b: int, k: int) -> dict:
        """The JSON object of camera k+1 of rig b (see ``ocalib calibrate-poses``)."""
        get = lambda name: getattr(self, name)[b, k].detach().cpu().double()  # noqa: E731
        unobs = get("translation_unobservable").bool()
        dirs = get("translation_directions")
        return {
            "rotation": get("rotation").tolist(),
            "quaternion_wxyz": get("quaternion").tolist(),
            "translation": get("translation").tolist(),
            "scale": float(get("scale")),
            "frames_used": int(get("frames_used")),
            "frames_rejected": int(get("frames_rejected")),
            "rotation_std_deg": _finite_or_none(torch.rad2deg(get("rotation_std"))),
            "translation_std": _finite_or_none(get("translation_std")),
            "scale_std": _finite_or_none(get("scale_std")),
            "observability": {
                "rotation_singular_values": get("rotation_singular_values").tolist(),
                "rotation_observable": bool(get("rotation_observable")),
                "planar_motion": bool(get("planar_motion")),
                "unobservable_translation_directions": [dirs[:, j].tolist() for j in range(3) if unobs[j]],
                "weakest_translation_direction": dirs[:, 0].tolist(),
            },
        }


def _finite_or_none(x: Tensor):
    """JSON has no infinity: unobservable (infinite) standard deviations become null."""
    values = [v if math.isfinite(v) else None for v in x.reshape(-1).tolist()]
    return values if x.dim() else values[0]
