"""Change detection of one camera's extrinsic from a stream of window estimates with their covariances.

Each window of the on-line rig estimator gives an estimate ``E_w`` of ``T_cam0_camk`` with a covariance ``P_w``.
:class:`ExtrinsicTrack` fuses them (information-weighted, each window's information divided by ``overlap``, the
number of windows a keyframe appears in, since overlapping windows share their data) and tests each new one
against the fused estimate: the innovation ``d`` (rotation vector and translation difference, camera 0's axes)
gives ``chi2 = d^T (P_w + P) ^-1 d`` on the observable directions. Bundle-adjustment covariances are lower bounds,
so ``chi2`` is divided by its own running median over the accepted windows (relative to the chi-square median of
its degrees of freedom, and never below 1) before it is compared with the chi-square quantile at
``false_alarm``. ``persistence`` windows in a row over it are a change: the track restarts from the newest window.

Convention: ``T_cam0_camk`` (``p_cam0 = R p_camk + t``); perturbations ``E = exp(d) E_fused`` with ``d`` =
(rotation rad, translation) in camera 0's axes.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import chi2 as chi2_distribution

HISTORY = 50  # normalised chi-square values the running median is taken over
UNINFORMED = 1e4  # the variance (rad^2, m^2) given to a direction the data do not inform


@dataclass
class Change:
    """A detected change: the first ``frame`` whose window disagreed, the ``detected`` frame, and the step from
    the old fused extrinsic to the new (rotation deg, translation in the estimate's units)."""

    frame: int
    detected: int
    rotation_change_deg: float
    translation_change: float


@dataclass
class ExtrinsicTrack:
    """The fused extrinsic of one camera: ``extrinsic`` (4, 4) and ``covariance`` (6, 6) (None before the first
    window), the last window's ``chi2`` (normalised), the ``changes`` detected."""

    overlap: float = 1.0
    false_alarm: float = 1e-4
    persistence: int = 2
    extrinsic: np.ndarray | None = None
    covariance: np.ndarray | None = None
    chi2: float = float("nan")
    changes: list[Change] = field(default_factory=list)
    _history: deque = field(default_factory=lambda: deque(maxlen=HISTORY))
    _pending: list = field(default_factory=list)

    def update(self, frame: int, extrinsic: np.ndarray, covariance: np.ndarray) -> Change | None:
        """Add the window estimate ``extrinsic`` (4, 4) with ``covariance`` (6, 6) ending at ``frame``; returns
        the change it completes, if any."""
        if self.extrinsic is None:
            self._restart(extrinsic, covariance)
            return None
        d = innovation(self.extrinsic, extrinsic)
        value, dof = chi_square(d, covariance + self.covariance)
        normalised = value / max(1.0, self._scale()) if dof else 0.0
        self.chi2 = normalised
        if dof and normalised > chi2_distribution.ppf(1 - self.false_alarm, dof):
            self._pending.append((frame, extrinsic, covariance))
            if len(self._pending) < self.persistence:
                return None
            change = Change(self._pending[0][0], frame, *_step(self.extrinsic, extrinsic))
            self.changes.append(change)
            self._restart(extrinsic, covariance)
            return change
        self._pending.clear()
        if dof:
            self._history.append(value / chi2_distribution.median(dof))
        self._fuse(extrinsic, covariance)
        return None

    def _scale(self) -> float:
        """The accepted windows' chi-square values over their chi-square medians, as a median (1 before 5)."""
        return float(np.median(self._history)) if len(self._history) >= 5 else 1.0

    def _restart(self, extrinsic: np.ndarray, covariance: np.ndarray) -> None:
        self.extrinsic, self.covariance = extrinsic.copy(), covariance * self.overlap
        self._pending.clear()

    def _fuse(self, extrinsic: np.ndarray, covariance: np.ndarray) -> None:
        """The information-weighted mean of the fused estimate and the window's (its information / overlap)."""
        info_old, info_new = _information(self.covariance), _information(covariance * self.overlap)
        info = info_old + info_new
        cov = np.linalg.pinv(info, hermitian=True)
        d = cov @ info_new @ innovation(self.extrinsic, extrinsic)
        self.extrinsic = perturbed(self.extrinsic, d)
        self.covariance = cov


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


def chi_square(d: np.ndarray, covariance: np.ndarray) -> tuple[float, int]:
    """``d^T P^-1 d`` on the directions the covariance ``P`` (6, 6) informs, and their count."""
    w, V = np.linalg.eigh(covariance)
    ok = (w > max(w.max(), 1e-300) * 1e-12) & (w < UNINFORMED / 10)
    z = V[:, ok].T @ d
    return float(np.sum(z**2 / w[ok])), int(ok.sum())


def _information(covariance: np.ndarray) -> np.ndarray:
    """The information (6, 6) of ``covariance``."""
    return np.linalg.pinv(covariance, hermitian=True, rcond=1e-12)


def _step(old: np.ndarray, new: np.ndarray) -> tuple[float, float]:
    d = innovation(old, new)
    return float(np.degrees(np.linalg.norm(d[:3]))), float(np.linalg.norm(d[3:]))
