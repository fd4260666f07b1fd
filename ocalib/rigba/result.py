"""What the rig bundle adjustment gives: :class:`RigAdjustment`, and each camera's JSON object in the format of
``calibrate-poses``.

Convention: ``T_cam0_camk`` (``p_cam0 = R p_camk + t``); trajectories are camera-to-world (N, 4, 4).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from ocalib.geometry.quaternion import rotation_matrix_to_quaternion
from ocalib.io.jsonable import finite_or_null
from ocalib.rigba.covariance import ExtrinsicUncertainty


@dataclass
class RigAdjustment:
    """The outcome of :func:`ocalib.rigba.adjust.adjust_rig`.

    ``extrinsics`` (C, 4, 4) ``T_cam0_camk`` in ``units``; ``trusted`` (C,) bool (camera 0 always True): where False
    the caller keeps the head's estimate (``warnings`` say why); ``uncertainty`` per camera k >= 1 (None when the
    reconstruction has none); ``scale`` (C,) camera k's front-end units into camera 0's (1 without a front end);
    ``trajectory`` (N, 4, 4) camera 0's camera-to-world pose in ``units`` at ``frames`` (NaN where not registered);
    ``registered`` (N, C) bool.
    """

    extrinsics: np.ndarray
    trusted: np.ndarray
    uncertainty: list[ExtrinsicUncertainty | None]
    scale: np.ndarray
    frames: np.ndarray
    trajectory: np.ndarray
    registered: np.ndarray
    units: str
    stats: dict = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


def camera_json(adjustment: RigAdjustment, k: int, online: dict) -> dict:
    """Camera k's (>= 1) JSON object in the format of ``calibrate-poses`` (``online``: the head's, whose
    rotation-system observability it keeps), with ``source`` ``"bundle_adjustment"``; the head's where not trusted."""
    if not adjustment.trusted[k]:
        return online | {"source": "online"}
    E = adjustment.extrinsics[k]
    u = adjustment.uncertainty[k]
    q = rotation_matrix_to_quaternion(torch.from_numpy(E[:3, :3])).numpy()
    registered = int(adjustment.registered[:, k].sum())
    observability = dict(online["observability"])
    if u is not None:
        weakest = u.unobservable[0] if len(u.unobservable) else _weakest(u.covariance[3:, 3:])
        observability.update(
            unobservable_translation_directions=u.unobservable.tolist(), weakest_translation_direction=weakest.tolist()
        )
    return {
        "camera": online["camera"],
        "rotation": E[:3, :3].tolist(),
        "quaternion_wxyz": (q if q[0] >= 0 else -q).tolist(),
        "translation": E[:3, 3].tolist(),
        "scale": float(adjustment.scale[k]),
        "time_offset": online["time_offset"],
        "frames_used": registered,
        "frames_rejected": len(adjustment.frames) - registered,
        "rotation_std_deg": None if u is None else np.degrees(u.rotation_std).tolist(),
        "translation_std": None if u is None else finite_or_null(u.translation_std.tolist()),
        "scale_std": None,
        "observability": observability,
        "residuals": {"reprojection_px": adjustment.stats.get("reprojection_error_px")},
        "source": "bundle_adjustment",
    }


def _weakest(cov: np.ndarray) -> np.ndarray:
    lam, V = np.linalg.eigh(cov)
    return V[:, -1]
