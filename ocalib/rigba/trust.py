"""Whether the rig bundle adjustment's extrinsics can be used: each camera's registered share, the reconstruction's
pieces and drift from a metric trajectory, a rotation moved far from every on-line estimate (the head's, the on-line
rig estimator's), an extrinsic the data do not determine, a lens missing from rig.yaml. A camera that fails keeps the
head's estimate; the warnings say why, and where a trusted result and the on-line rig estimator's disagree.
"""

from __future__ import annotations

import math

import numpy as np

from ocalib.data.sequence import Sequence
from ocalib.geometry.se3 import rotation_angle_deg
from ocalib.rigba.result import RigAdjustment

MAX_ROTATION_CHANGE_DEG = 5.0  # a bundle-adjusted rotation this far from the head's is not trusted
MIN_REGISTERED = 0.5  # share of a camera's frames below which its extrinsic is not trusted
WARN_REGISTERED = 0.9  # share below which the missing frames are reported
MIN_KEYPOINTS = 100  # median keypoints an image below which the images are reported as too poor in features
MAX_DRIFT = 0.05  # RMS position error over the path length, after the Sim(3) fit to a metric trajectory
MAX_ROTATION_STD_DEG = 1.0  # a rotation 1-sigma above this (deg, any axis): the images do not determine the camera
DISAGREE_DEG = 1.0  # a trusted rotation and the on-line rig estimator's this far apart (twice a car's target): said


def checks(
    out: RigAdjustment,
    sequence: Sequence,
    initial: np.ndarray,
    models: list,
    keypoints: float,
    estimator: np.ndarray | None = None,
) -> list[str]:
    """Warnings on what went wrong, and ``out.trusted`` cleared for the cameras whose extrinsic cannot be used.
    A camera's rotation must stay near the head's ``initial`` (C, 4, 4; NaN where not to be checked against) or the
    on-line rig estimator's ``estimator`` (C, 4, 4, where it ran); a trusted result far from the estimator's is said
    (:func:`disagreements`)."""
    estimator = np.full_like(initial, np.nan) if estimator is None else estimator
    warnings = []
    names = sequence.names
    N = len(out.frames)
    if keypoints < MIN_KEYPOINTS:
        warnings.append(
            f"bundle adjustment: {keypoints:.0f} keypoints an image (median): the images are poor in "
            "texture, the result is weak"
        )
    if len(models) > 1:
        warnings.append(
            f"bundle adjustment: the reconstruction fell apart into {len(models)} pieces; the largest, "
            f"{models[0].num_reg_frames()} of {N} frames, is used"
        )
    for k, name in enumerate(names):
        share = out.registered[:, k].mean()
        if share < WARN_REGISTERED:
            missing = np.flatnonzero(~out.registered[:, k])
            warnings.append(
                f"bundle adjustment: {name}: {N - out.registered[:, k].sum()} of {N} frames did not "
                f"register (first: frame {out.frames[missing[0]]})"
            )
        if share < MIN_REGISTERED:
            out.trusted[k] = False
        if out.stats.get("lens_missing", [False] * len(names))[k]:
            warnings.append(
                f"bundle adjustment: {name}: its residuals grow towards the image corners "
                f"({out.stats['radial_residual_corner_px'][k]:+.1f} px there): its lens distortion is missing from "
                "rig.yaml, or wrong"
            )
            out.trusted[k] = False
    if not out.trusted[0]:
        out.trusted[:] = False
    if out.stats.get("drift", 0.0) > MAX_DRIFT:
        warnings.append(
            f"bundle adjustment: the reconstruction drifts from the metric trajectory (RMS "
            f"{out.stats['drift']:.1%} of the path length)"
        )
        out.trusted[:] = False
    for k in range(1, len(names)):
        change = float(
            np.fmin(*(rotation_angle_deg(out.extrinsics[k, :3, :3].T @ r[k, :3, :3]) for r in (initial, estimator)))
        )
        if change > MAX_ROTATION_CHANGE_DEG:  # False for NaN: not checked
            warnings.append(
                f"bundle adjustment: {names[k]}: the rotation moved {change:.1f} deg from the on-line "
                "estimate; not trusted"
            )
            out.trusted[k] = False
    for k in range(1, len(names)):
        u = out.uncertainty[k]
        std = math.inf if u is None else float(np.degrees(u.rotation_std).max())
        if not std <= MAX_ROTATION_STD_DEG or (u is not None and len(u.unobservable) == 3):  # NaN: not determined
            warnings.append(
                f"bundle adjustment: {names[k]}: the reconstruction does not determine its extrinsic (rotation "
                f"1-sigma {std:.2g} deg, {3 if u is None else len(u.unobservable)} of 3 translation directions "
                "unobservable)"
            )
            out.trusted[k] = False
    for k in np.flatnonzero(~out.trusted[1:]) + 1:
        warnings.append(f"bundle adjustment: {names[k]}: the on-line estimate is kept")
    unchecked = np.isnan(initial[1:, 0, 0]) & np.isnan(estimator[1:, 0, 0])  # no on-line rotation known
    for k in np.flatnonzero(out.trusted[1:] & unchecked) + 1:
        warnings.append(
            f"bundle adjustment: {names[k]}: the motion does not determine its rotation for the on-line head (too "
            "little turning); the adjustment's rests on the images alone, unchecked, and its 1-sigma may understate "
            "its error"
        )
    out.trusted[0] = True
    return warnings + disagreements(out, names, estimator)


def disagreements(out: RigAdjustment, names: list[str], estimate: np.ndarray) -> list[str]:
    """A warning per trusted camera k >= 1 whose rotation and ``estimate``'s (C, 4, 4; NaN: none) are ``DISAGREE_DEG``
    or more apart: at least one of the two is off (the estimator after a late start, the adjustment on a drive that
    turns too little). The rotations only: both pin a car's camera height too loosely to compare translations."""
    said = []
    for k in np.flatnonzero(out.trusted[1:] & np.isfinite(estimate[1:, 0, 0])) + 1:
        angle = float(rotation_angle_deg(out.extrinsics[k, :3, :3].T @ estimate[k, :3, :3]))
        if angle >= DISAGREE_DEG:
            said.append(
                f"bundle adjustment: {names[k]}: its rotation and the on-line rig estimator's are {angle:.2f} deg "
                "apart: one of them is off (the estimator after a late start, or the adjustment on a drive that turns "
                "too little)"
            )
    return said
