"""One camera's extrinsic as the on-line rig estimator keeps it: the window estimates fused, and a change of the
mounting told from noise.

:meth:`ExtrinsicTrack.fuse` adds a window estimate ``E_w`` with its covariance ``P_w``: information-weighted, each
window's information divided by ``overlap`` (the number of windows a keyframe appears in: overlapping windows
share their data). :meth:`ExtrinsicTrack.observe` tests one keyframe's own measurement of the extrinsic (camera k's pose resected
from its 2-D-3-D matches, composed with the rig's pose) against the fused estimate: the rotation part of the
innovation ``d`` (rotation vector, camera 0's axes) gives ``chi2 = d^T (S + P)^-1 d`` with ``S`` the measurement's
covariance and ``P`` the fused estimate's, divided by the running median of the accepted values over the
chi-square median (never below 1: these covariances are lower bounds, and the division keeps the test's level on
any rig). Over the chi-square quantile at ``false_alarm`` on ``persistence`` keyframes in a row, whose measurements
agree with their mean (a bad resection disagrees with the fused estimate too, but not in one consistent way), is a
change: the track restarts from that mean. The rotation alone, since one keyframe's resected position
is too noisy to tell a knock from noise; a knock that only shifts a camera goes unnoticed.

Convention: ``T_cam0_camk`` (``p_cam0 = R p_camk + t``); perturbations ``E = exp(d) E_fused`` with ``d`` =
(rotation rad, translation) in camera 0's axes.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import chi2 as chi2_distribution

HISTORY = 50  # accepted chi-square values whose median normalises the test
MIN_HISTORY = 10  # values needed before the test runs
AGREEMENT = 0.01  # the disagreeing measurements must agree with their mean at this level to be one new mounting
UNINFORMED = 1e4  # the variance (rad^2, m^2) given to a direction the data do not inform


@dataclass
class Change:
    """A detected change: the first ``frame`` that disagreed, the ``detected`` frame, and the step from the old
    fused extrinsic to the mean of the disagreeing measurements (rotation deg, translation in metres)."""

    frame: int
    detected: int
    rotation_change_deg: float
    translation_change: float


@dataclass
class ExtrinsicTrack:
    """The fused extrinsic of one camera: ``extrinsic`` (4, 4) and ``covariance`` (6, 6) (None before the first
    window), the last keyframe's normalised change statistic ``chi2``, the ``changes`` detected."""

    overlap: float = 1.0
    false_alarm: float = 1e-4
    persistence: int = 3
    extrinsic: np.ndarray | None = None
    covariance: np.ndarray | None = None
    chi2: float = float("nan")
    changes: list[Change] = field(default_factory=list)
    _history: deque = field(default_factory=lambda: deque(maxlen=HISTORY))
    _pending: list = field(default_factory=list)

    def fuse(self, extrinsic: np.ndarray, covariance: np.ndarray) -> None:
        """Add the window estimate ``extrinsic`` (4, 4) with ``covariance`` (6, 6)."""
        info_new = _information(covariance * self.overlap)
        if self.extrinsic is None:
            self.extrinsic, self.covariance = extrinsic.copy(), covariance * self.overlap
            return
        info = _information(self.covariance) + info_new
        cov = np.linalg.pinv(info, hermitian=True)
        self.extrinsic = perturbed(self.extrinsic, cov @ info_new @ innovation(self.extrinsic, extrinsic))
        self.covariance = cov

    def observe(self, frame: int, extrinsic: np.ndarray, rotation_covariance: np.ndarray) -> Change | None:
        """Test one keyframe's measurement ``extrinsic`` (4, 4), its rotation's covariance (3, 3) (rad^2, camera 0's
        axes) -> the change it completes, if any."""
        if self.extrinsic is None:
            return None
        d = innovation(self.extrinsic, extrinsic)
        value = float(d[:3] @ np.linalg.solve(rotation_covariance + self.covariance[:3, :3], d[:3]))
        self.chi2 = value / self._scale()
        if len(self._history) < MIN_HISTORY or self.chi2 <= chi2_distribution.ppf(1 - self.false_alarm, 3):
            self._pending.clear()
            self._history.append(value)
            return None
        self._pending.append((frame, extrinsic, rotation_covariance))
        if len(self._pending) < self.persistence:
            return None
        steps = np.stack([innovation(self.extrinsic, E) for _, E, _ in self._pending])
        step = steps.mean(0)
        agree = [float((d[:3] - step[:3]) @ np.linalg.solve(S, d[:3] - step[:3])) / self._scale() for d, (_, _, S) in
                 zip(steps, self._pending)]  # fmt: skip
        if max(agree) > chi2_distribution.ppf(1 - AGREEMENT, 3):  # outliers, not one new mounting: slide on
            self._pending.pop(0)
            return None
        new = perturbed(self.extrinsic, step)
        change = Change(self._pending[0][0], frame, *_step(self.extrinsic, new))
        self.changes.append(change)
        self.extrinsic, self.covariance = new.copy(), np.eye(6) * UNINFORMED
        self._history.clear()
        self._pending.clear()
        return change

    def _scale(self) -> float:
        """How many times the chi-square median (3 degrees of freedom) the accepted values are, as a median; at
        least 1 (the covariances are lower bounds, never upper ones)."""
        if len(self._history) < MIN_HISTORY:
            return 1.0
        return max(1.0, float(np.median(self._history)) / chi2_distribution.median(3))


def innovation(reference: np.ndarray, estimate: np.ndarray) -> np.ndarray:
    """(6,) ``d`` with ``estimate = exp(d) reference``: rotation vector (rad) and translation difference."""
    rotation = Rotation.from_matrix(estimate[:3, :3] @ reference[:3, :3].T).as_rotvec()
    return np.concatenate([rotation, estimate[:3, 3] - reference[:3, 3]])


def perturbed(reference: np.ndarray, d: np.ndarray) -> np.ndarray:
    """``exp(d) reference`` (4, 4), the inverse of :func:`innovation`."""
    out = reference.copy()
    out[:3, :3] = Rotation.from_rotvec(d[:3]).as_matrix() @ reference[:3, :3]
    out[:3, 3] = reference[:3, 3] + d[3:]
    return out


def with_unobservable(covariance: np.ndarray, unobservable: np.ndarray) -> np.ndarray:
    """``covariance`` (6, 6) with :data:`UNINFORMED` variance along the ``unobservable`` (n, 3) unit translation
    directions (where a bundle adjustment's covariance has none)."""
    out = covariance.copy()
    out[3:, 3:] += UNINFORMED * unobservable.T @ unobservable
    return out


def _information(covariance: np.ndarray) -> np.ndarray:
    """The information (6, 6) of ``covariance``."""
    return np.linalg.pinv(covariance, hermitian=True, rcond=1e-12)


def _step(old: np.ndarray, new: np.ndarray) -> tuple[float, float]:
    d = innovation(old, new)
    return float(np.degrees(np.linalg.norm(d[:3]))), float(np.linalg.norm(d[3:]))
