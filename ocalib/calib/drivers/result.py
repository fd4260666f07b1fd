"""The calibration estimate of one frame, as tensors, and its JSON form."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from functools import cached_property

import numpy as np
import torch
from torch import Tensor

from ocalib.calib.stages.handeye import TranslationMoment, translation_quadratic
from ocalib.calib.stages.planar import planar_rotation_std
from ocalib.calib.stages.refine import costs, joint_covariance
from ocalib.calib.stages.rotation import RotationSystem, rotation_gram, rotation_std
from ocalib.calib.stages.translation import translation_uncertainty, unobservable_directions
from ocalib.io.jsonable import finite_or_null


@dataclass
class Calibration:
    """Extrinsics of cameras 1..K against camera 0 for B rigs, with their observability.

    Convention: ``rotation``/``translation`` form ``T_cam0_camk``, the pose of camera k in camera 0's
    frame (``p_cam0 = R p_camk + t``); ``scale`` multiplies camera-k trajectory units into camera-0
    units; quaternions are (w, x, y, z), w >= 0. Shapes lead with (B, K).

    The uncertainty (``*_std``, ``translation_*``) is computed from the solver's state when first read,
    so a stream that does not look at it does not pay for it. Where the estimate was refined jointly
    (``refined``), the standard deviations are those of the joint solve
    (:func:`~ocalib.calib.stages.refine.joint_covariance`: rotation, translation and scale together); elsewhere those of
    the closed forms (rotation system, then translation with the rotation fixed; planar motion: the planar route).
    """

    rotation: Tensor  # (B, K, 3, 3)
    quaternion: Tensor  # (B, K, 4)
    translation: Tensor  # (B, K, 3)
    scale: Tensor  # (B, K)
    rotation_singular_values: Tensor  # (B, K, 4), descending
    rotation_observable: Tensor  # (B, K) bool
    planar_motion: Tensor  # (B, K) bool
    planar_axis: Tensor  # (B, K, 3) common rotation axis (camera 0's frame) where planar_motion
    frames_used: Tensor  # (B, K) long
    frames_rejected: Tensor  # (B, K) long
    rotation_basis: Tensor  # (B, K, 4, 4) right singular vectors of the rotation system
    rotation_rows: Tensor  # (B, K) weighted motion pairs in the rotation system
    translation_moment: Tensor  # (B, K, 58) the translation rows' statistics, see ocalib.calib.stages.handeye
    translation_rows: Tensor  # (B, K) weighted motion pairs in the translation system
    refined: Tensor | None = None  # (B, K) bool: the joint refinement was applied (None: nowhere)
    translation_moment_reverse: Tensor | None = None  # (B, K, 58) the reverse rows' share (None: not kept)

    @classmethod
    def from_statistics(
        cls, est: dict[str, Tensor], rotation: RotationSystem, moment: TranslationMoment, frames_used, frames_rejected
    ) -> Calibration:
        """The estimate ``est`` (:func:`~ocalib.calib.stages.solve.closed_form`, refined) with the statistics it came
        from."""
        return cls(**est, rotation_basis=rotation.V, rotation_rows=rotation.rotation_rows, translation_moment=moment.Z,
                   translation_rows=moment.translation_rows, translation_moment_reverse=moment.Z_reverse,
                   frames_used=frames_used, frames_rejected=frames_rejected)  # fmt: skip

    @cached_property
    def _joint(self) -> Tensor | None:
        """(B, K, 7) joint 1-sigma (rotation (3), scale, translation (3)) where refined, else inf; None if nowhere."""
        if self.refined is None or not bool(self.refined.any()):
            return None
        r = self.refined
        S2, V = self.rotation_singular_values[r].square(), self.rotation_basis[r]
        x = torch.cat([self.translation[r], self.scale[r].unsqueeze(-1)], -1)
        reverse = self.translation_moment_reverse
        reverse = None if reverse is None else translation_quadratic(reverse[r])
        cov = joint_covariance(rotation_gram(S2, V), translation_quadratic(self.translation_moment[r]),
                               self.quaternion[r], x, self.rotation_rows[r], self.translation_rows[r],
                               reverse)  # fmt: skip
        std = torch.full((*r.shape, 7), math.inf, dtype=x.dtype, device=x.device)
        return std.index_put((r,), torch.diagonal(cov, dim1=-2, dim2=-1).sqrt())

    @cached_property
    def rotation_std(self) -> Tensor:
        """(B, K, 3) 1-sigma rotation error in radians about camera k's axes (planar motion: from the planar
        route, see :func:`~ocalib.calib.stages.planar.planar_rotation_std`); inf where the residual says nothing."""
        std = rotation_std(self.rotation_singular_values, self.rotation_basis, self.rotation_rows)
        planar = self.planar_motion
        if bool(planar.any()):  # the rotation system is degenerate there: the planar route's own uncertainty
            quadratic = translation_quadratic(self.translation_moment[planar])
            std_planar = planar_rotation_std(quadratic, self.rotation_singular_values[planar],
                                             self.rotation_basis[planar], self.quaternion[planar],
                                             self.rotation_rows[planar], self.translation_rows[planar])  # fmt: skip
            std = std.index_put((planar,), std_planar)
        if self._joint is not None:
            std = torch.where(self.refined.unsqueeze(-1), self._joint[..., :3], std)
        return std

    @cached_property
    def _translation(self) -> dict[str, Tensor]:
        x = torch.cat([self.translation, self.scale.unsqueeze(-1)], -1)
        out = translation_uncertainty(self.translation_moment, self.rotation, x, self.translation_rows)
        unobservable = unobservable_directions(out["information"])
        along_axis = (out["directions"] * self.planar_axis.unsqueeze(-1)).sum(-2).abs() > 0.9
        out["unobservable"] = unobservable | (self.planar_motion.unsqueeze(-1) & along_axis)
        return out

    @property
    def translation_information(self) -> Tensor:
        """(B, K, 3) information on dT (s free), ascending; its eigenvectors are ``translation_directions``."""
        return self._translation["information"]

    @property
    def translation_directions(self) -> Tensor:
        """(B, K, 3, 3) eigenvectors (columns, camera 0's frame) of the translation information."""
        return self._translation["directions"]

    @property
    def translation_unobservable(self) -> Tensor:
        """(B, K, 3) bool: which ``translation_directions`` carry no information (planar: the axis)."""
        return self._translation["unobservable"]

    @property
    def translation_std(self) -> Tensor:
        """(B, K, 3) 1-sigma along camera 0's axes; inf for an axis with a share of an unobservable direction."""
        leak = (self.translation_directions**2 * self.translation_unobservable.unsqueeze(-2)).sum(-1) > 0.01
        std = torch.diagonal(self._translation["covariance"][..., :3, :3], dim1=-2, dim2=-1).sqrt()
        if self._joint is not None:
            std = torch.where(self.refined.unsqueeze(-1), self._joint[..., 4:], std)
        return torch.where(leak, math.inf, std)

    @property
    def scale_std(self) -> Tensor:
        """(B, K) 1-sigma of the scale; inf where it is unobservable or the system exactly determined."""
        std = self._translation["covariance"][..., 3, 3].sqrt()
        if self._joint is not None:
            std = torch.where(self.refined, self._joint[..., 3], std)
        return torch.where(self._translation["scale_unobservable"], torch.inf, std)

    @cached_property
    def residuals(self) -> dict[str, Tensor]:
        """How well the estimate explains the motions, (B, K) each (NaN without rows), weighted as the solver weighs
        them: ``rotation_deg``, the RMS over motion pairs of the angle between camera 0's motion carried into
        camera k's frame by the estimate and camera k's own motion (``2 |A q|`` a pair, to first order), and
        ``translation_relative``, the RMS of the translation equations' residual over the RMS length of camera 0's
        motion translations (0: explained; 1: no better than no translation at all)."""
        S2, V = self.rotation_singular_values.square(), self.rotation_basis
        P, p, c = translation_quadratic(self.translation_moment)
        x = torch.cat([self.translation, self.scale.unsqueeze(-1)], -1)
        Er, Et = costs(rotation_gram(S2, V), P, p, c, self.quaternion, x)
        rows = self.rotation_rows
        rotation = torch.where(rows > 0, 2 * (Er.clamp_min(0) / rows.clamp_min(1e-300)).sqrt(), torch.nan)
        translation = torch.where(c > 0, (Et.clamp_min(0) / c.clamp_min(1e-300)).sqrt(), torch.nan)
        return {"rotation_deg": torch.rad2deg(rotation), "translation_relative": translation}

    def with_camera(self, k: int, other: Calibration) -> Calibration:
        """This estimate with camera k+1's fields (every rig's) replaced by camera 1's of ``other`` (B, 1, ...)."""

        def spliced(mine: Tensor | None, theirs: Tensor | None) -> Tensor | None:
            if mine is None or theirs is None:
                return mine
            out = mine.clone()
            out[:, k] = theirs[:, 0]
            return out

        return type(self)(**{f.name: spliced(getattr(self, f.name), getattr(other, f.name)) for f in fields(self)})

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
            "rotation_std_deg": finite_or_null(torch.rad2deg(get("rotation_std")).tolist()),
            "translation_std": finite_or_null(get("translation_std").tolist()),
            "scale_std": finite_or_null(get("scale_std").tolist()),
            "residuals": finite_or_null({name: float(v[b, k]) for name, v in self.residuals.items()}),
            "observability": {
                "rotation_singular_values": get("rotation_singular_values").tolist(),
                "rotation_observable": bool(get("rotation_observable")),
                "planar_motion": bool(get("planar_motion")),
                "unobservable_translation_directions": [dirs[:, j].tolist() for j in range(3) if unobs[j]],
                "weakest_translation_direction": dirs[:, 0].tolist(),
            },
        }


def planar_axes(estimate: Calibration) -> np.ndarray:
    """(K, 3) per camera k >= 1 of rig 0, the axis the rig turns about where the head found its motion planar (a
    car's vertical; camera 0's axes), NaN rows elsewhere: the normal of the ground plane a car's translation is
    compared in, by every stage alike."""
    axes = estimate.planar_axis[0].double().cpu().numpy().copy()
    axes[~estimate.planar_motion[0].cpu().numpy()] = np.nan
    return axes
