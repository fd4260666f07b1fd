"""One camera's extrinsic as the on-line rig estimator keeps it: the window estimates fused, and a change of the
mounting told from noise.

:meth:`ExtrinsicTrack.fuse` adds a window estimate ``E_w`` with its covariance ``P_w``: information-weighted, each
window's information divided by ``overlap`` (the number of windows a keyframe appears in: overlapping windows
share their data). :meth:`ExtrinsicTrack.observe` tests one keyframe's own measurement of the extrinsic (camera
k's pose resected from its 2-D-3-D matches, composed with the rig's pose) against the fused estimate: the
innovation ``d`` (rotation vector and translation difference, camera 0's axes), less the mean of the recent
accepted ones, gives ``chi2 = d^T S^-1 d`` with ``S`` their covariance (the spread the measurements show on a steady
rig, which the covariances of a bundle adjustment understate). Over the chi-square quantile at ``false_alarm`` on
``persistence`` keyframes in a row is a change: the track restarts from their mean.

Convention: ``T_cam0_camk`` (``p_cam0 = R p_camk + t``); perturbations ``E = exp(d) E_fused`` with ``d`` =
(rotation rad, translation) in camera 0's axes.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import chi2 as chi2_distribution

from ocalib.calib.change import Change, step_size

HISTORY = 30  # accepted innovations whose spread the test uses
MIN_HISTORY = 10  # innovations needed before the test runs
UNINFORMED = 1e4  # the variance (rad^2, m^2) given to a direction the data do not inform


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

    def observe(self, frame: int, extrinsic: np.ndarray) -> Change | None:
        """Test one keyframe's measurement ``extrinsic`` (4, 4) -> the change it completes, if any."""
        if self.extrinsic is None:
            return None
        d = innovation(self.extrinsic, extrinsic)
        if len(self._history) < MIN_HISTORY:
            self._history.append(d)
            return None
        history = np.stack(self._history)
        spread = np.cov(history.T) + np.diag(np.maximum(history.var(0), 1e-12)) * 0.1  # shrunk toward its diagonal
        z = d - history.mean(0)
        self.chi2 = float(z @ np.linalg.solve(spread, z))
        if self.chi2 <= chi2_distribution.ppf(1 - self.false_alarm, 6):
            self._pending.clear()
            self._history.append(d)
            return None
        self._pending.append((frame, extrinsic))
        if len(self._pending) < self.persistence:
            return None
        step = np.mean([innovation(self.extrinsic, E) for _, E in self._pending], axis=0)
        new = perturbed(self.extrinsic, step)
        change = Change(
            self._pending[0][0],
            frame,
            *step_size(self.extrinsic[:3, :3], self.extrinsic[:3, 3], new[:3, :3], new[:3, 3]),
        )
        self.changes.append(change)
        self.extrinsic, self.covariance = new.copy(), np.eye(6) * UNINFORMED
        self._history.clear()
        self._pending.clear()
        return change


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
