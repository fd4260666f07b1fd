"""One camera's extrinsic as the on-line rig estimator keeps it: the window estimates fused, and a change of the
mounting told from noise.

:meth:`ExtrinsicTrack.fuse` adds a window estimate ``E_w`` with its covariance ``P_w``: the estimate is the windows'
information-weighted mean, its covariance the inverse of their *mean* information (covariance intersection with
equal weights, consistent whatever the windows' correlation): overlapping windows share keyframes and points, and
their errors persist well beyond a window's span, so the fused estimate is stated no better known than its windows.
:meth:`ExtrinsicTrack.observe` tests one keyframe's own measurement ``E_k`` of the extrinsic (camera k resected from
its 2-D-3-D inliers, composed with the rig's pose) against the window's: with ``d`` the
innovation from ``E_w`` to ``E_k``, ``I_k`` the keyframe's information (:func:`information`), the statistic
``d^T (I_k^-1 + P_w)^-1 d`` is chi-square with 6 degrees of freedom on a steady rig, up to an overdispersion (the
points are estimates, shared by neighbouring keyframes) taken as the median of the recent steady statistics over
the distribution's median, when above 1 (1 before any: the test runs from the camera's first tested keyframe, for a
knock just after the window determined it). Over the quantile at ``false_alarm`` on ``persistence`` tested keyframes
in a row is a candidate change; the caller confirms it, at one of its disagreeing keyframes
(:meth:`ExtrinsicTrack.candidate_from`, then :meth:`ExtrinsicTrack.accept`: the track restarts from the keyframes'
mean measurement from there) or not (:meth:`ExtrinsicTrack.dismiss`).

:meth:`ExtrinsicTrack.drifted` catches what the keyframes' test misses where the window follows a change within a
few keyframes (they then agree with it): each window estimate, before it is fused, against the track, ``d^T (P +
P_w)^-1 d`` with ``d`` the innovation from the track's ``E`` to ``E_w``; the track holds the windows before it, so on a
steady rig the statistic sits well under a chi-square with 6 degrees of freedom, and over its quantile at
``DRIFT_FALSE_ALARM`` on ``persistence`` windows in a row, by a step of at least ``min_change``, is a change whose
candidate is the window's estimate (the caller accepts it: :meth:`ocalib.rigba.camera_state.CameraState.restart`).

Convention: ``T_cam0_camk`` (``p_cam0 = R p_camk + t``); perturbations ``E = exp(d) E_ref`` with ``d`` =
(rotation rad, translation) in camera 0's axes; rig poses camera-to-world (4, 4).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2 as chi2_distribution

from ocalib.calib.drivers.change import Change, step_size
from ocalib.data.distortion import project
from ocalib.geometry.se3 import cross_matrix, innovation, perturbed

HISTORY = 30  # steady keyframes whose statistics give the overdispersion
UNINFORMED = 1e4  # the variance (rad^2, m^2) given to a direction the data do not inform
CHI2_MEDIAN = float(chi2_distribution.median(6))
DRIFT_FALSE_ALARM = 1e-6  # drifted's level; steady rigs stay far below it (docs/results-rig-online.md)


@dataclass
class ExtrinsicTrack:
    """The fused extrinsic of one camera: ``extrinsic`` (4, 4) and ``covariance`` (6, 6) (None before the first
    window), the last keyframe's normalised change statistic ``chi2``, the ``changes`` accepted, and the extrinsic
    the ``candidate`` change raised last would give (``_disagreeing``: the tested keyframes in a row that disagree
    with the window: frame, measurement and the window's extrinsic)."""

    false_alarm: float = 1e-8
    persistence: int = 2
    min_change: tuple[float, float] = (0.0, 0.0)  # the least step (rotation deg, translation) :meth:`drifted` takes
    extrinsic: np.ndarray | None = None
    covariance: np.ndarray | None = None
    chi2: float = float("nan")
    changes: list[Change] = field(default_factory=list)
    candidate: np.ndarray | None = None
    disagreed: list = field(default_factory=list)  # the candidate's keyframes: (frame, measurement, window's)
    windows: int = 0  # window estimates fused since the start or the last change
    _information_sum: np.ndarray = field(default_factory=lambda: np.eye(6) / UNINFORMED)
    _history: deque = field(default_factory=lambda: deque(maxlen=HISTORY))
    _disagreeing: list = field(default_factory=list)
    _drifting: list = field(default_factory=list)

    def fuse(self, extrinsic: np.ndarray, covariance: np.ndarray) -> None:
        """Add the window estimate ``extrinsic`` (4, 4) with ``covariance`` (6, 6)."""
        info_new = _information(covariance)
        self._information_sum = self._information_sum + info_new
        self.windows += 1
        if self.extrinsic is None:
            self.extrinsic = extrinsic.copy()
        else:
            step = _information(self._information_sum, UNINFORMED) @ info_new @ innovation(self.extrinsic, extrinsic)
            self.extrinsic = perturbed(self.extrinsic, step)
        self.covariance = _information(self._information_sum / self.windows, UNINFORMED)

    def drifted(self, frame: int, extrinsic: np.ndarray, covariance: np.ndarray) -> Change | None:
        """Test the window estimate ``extrinsic`` (4, 4) with ``covariance`` (6, 6) at keyframe ``frame`` against the
        track, before it is fused -> the change it completes, if any, its ``candidate`` the window's estimate, to
        :meth:`accept` (the track then holds the window's estimate, uninformed). The change's frame is the first
        window of the run over the level (the change happened before it)."""
        if self.extrinsic is None:
            return None
        d = innovation(self.extrinsic, extrinsic)
        try:
            statistic = float(d @ np.linalg.solve(self.covariance + covariance, d))
        except np.linalg.LinAlgError:
            return None
        if not (statistic > chi2_distribution.ppf(1 - DRIFT_FALSE_ALARM, 6) and reaches(d, self.min_change)):
            self._drifting.clear()
            return None
        self._drifting.append(frame)
        if len(self._drifting) < self.persistence:
            return None
        before = self.extrinsic
        self.candidate = extrinsic.copy()
        change = Change(self._drifting[0], frame, *step_size(before[:3, :3], before[:3, 3], extrinsic[:3, :3],
                                                             extrinsic[:3, 3]))  # fmt: skip
        return change

    @property
    def disagrees(self) -> bool:
        """Whether the last keyframes disagree with the window, short of a change yet."""
        return bool(self._disagreeing)

    def observe(
        self, frame: int, extrinsic: np.ndarray, info: np.ndarray, reference: tuple[np.ndarray, np.ndarray]
    ) -> Change | None:
        """Test one keyframe's measurement ``extrinsic`` (4, 4) with its information ``info`` (6, 6)
        (:func:`information`) against ``reference``, the window's ``(extrinsic (4, 4), covariance (6, 6))`` -> the
        candidate change it completes, if any, to :meth:`accept` or :meth:`dismiss`."""
        if self.extrinsic is None or not np.isfinite(info).all():
            return None
        d = innovation(reference[0], extrinsic)
        try:
            statistic = float(d @ np.linalg.solve(np.linalg.inv(info) + reference[1], d))
        except np.linalg.LinAlgError:
            return None
        overdispersion = max(float(np.median(self._history)) / CHI2_MEDIAN, 1.0) if self._history else 1.0
        self.chi2 = statistic / overdispersion
        if self.chi2 <= chi2_distribution.ppf(1 - self.false_alarm, 6):
            self._disagreeing.clear()
            self._history.append(statistic)
            return None
        self._disagreeing.append((frame, extrinsic, reference[0]))
        if len(self._disagreeing) < self.persistence or self.candidate is not None:  # one awaits judgement
            return None
        self.disagreed = list(self._disagreeing)
        return self.candidate_from(self._disagreeing[0][0], frame)

    def candidate_from(self, frame: int, detected: int) -> Change:
        """The candidate change as from its disagreeing keyframe ``frame`` on (noticed at keyframe ``detected``): its
        extrinsic (``candidate``) the mean measurement of the disagreeing keyframes from there, its size the step to
        it from the window's extrinsic that keyframe was tested against (before the window could follow)."""
        before = next(reference for f, _, reference in self.disagreed if f == frame)
        step = np.mean([innovation(before, E) for f, E, _ in self.disagreed if f >= frame], axis=0)
        self.candidate = after = perturbed(before, step)
        return Change(frame, detected, *step_size(before[:3, :3], before[:3, 3], after[:3, :3], after[:3, 3]))

    def accept(self, change: Change) -> None:
        """The candidate ``change`` is real: record it and restart the track from its extrinsic, uninformed."""
        self.changes.append(change)
        self.extrinsic, self.covariance = self.candidate, np.eye(6) * UNINFORMED
        self.windows, self._information_sum = 0, np.eye(6) / UNINFORMED
        self._history.clear()
        self.dismiss()

    def dismiss(self) -> None:
        """Forget the candidate and the disagreeing keyframes or windows: they were wrong, not the window."""
        self._disagreeing.clear()
        self._drifting.clear()
        self.candidate, self.disagreed = None, []


def information(xy: np.ndarray, xyz: np.ndarray, K: np.ndarray, pose: np.ndarray, extrinsic: np.ndarray) -> np.ndarray:
    """The information (6, 6) a keyframe's keypoints ``xy`` (n, 2) (pixels) of points ``xyz`` (n, 3) give about the
    camera's ``extrinsic`` (4, 4) on the rig at ``pose`` (4, 4): ``J^T J / sigma^2``, J the reprojection's derivative
    in the perturbation ``d`` of ``exp(d) extrinsic`` (central differences), sigma^2 the residuals' variance per axis
    (their median squared error over ``2 ln 2``, a chi-square's median with 2 degrees of freedom). K (3, 3)."""

    def residuals(E):
        cam_from_world = np.linalg.inv(pose @ E)
        return (project(xyz @ cam_from_world[:3, :3].T + cam_from_world[:3, 3], K, None) - xy).ravel()

    step = 1e-6
    J = np.stack([(residuals(perturbed(extrinsic, step * e)) - residuals(perturbed(extrinsic, -step * e))) / (2 * step)
                  for e in np.eye(6)], axis=1)  # fmt: skip
    variance = float(np.median((residuals(extrinsic).reshape(-1, 2) ** 2).sum(1))) / (2 * np.log(2))
    return J.T @ J / variance


def relative_information(info: np.ndarray, reference_info: np.ndarray, extrinsic: np.ndarray) -> np.ndarray:
    """The information (6, 6) of a keyframe's ``extrinsic`` (4, 4) measured against camera 0's own resection:
    ``info`` (camera k's, camera 0 held) with camera 0's uncertainty added, ``reference_info`` its information about
    a perturbation ``pose exp(d0)`` of its pose (:func:`information` with the identity extrinsic), which moves the
    measurement by ``-d0`` and its translation by ``t x w0``. NaN where either is."""
    A = -np.eye(6)
    A[3:, :3] = cross_matrix(extrinsic[:3, 3])
    with np.errstate(invalid="ignore"):
        try:
            covariance = np.linalg.inv(info) + A @ np.linalg.inv(reference_info) @ A.T
            return np.linalg.inv(covariance)
        except np.linalg.LinAlgError:
            return np.full((6, 6), np.nan)


def reaches(d: np.ndarray, least: tuple[float, float]) -> bool:
    """Whether the step ``d`` (6,) (see :func:`innovation`) is at least ``least``: its rotation (deg) or its
    translation (m). False for NaN."""
    return bool(np.degrees(np.linalg.norm(d[:3])) >= least[0] or np.linalg.norm(d[3:]) >= least[1])


def determines(covariance: np.ndarray, least: tuple[float, float]) -> bool:
    """Whether ``covariance`` (6, 6) (rotation rad, translation m; :data:`UNINFORMED` along what the data do not
    inform) determines an extrinsic: its rotation's 1-sigma under ``least[0]`` deg about every axis, its
    translation's under ``least[1]`` m along the two best-determined directions (planar motion never pins a car's
    height). False where a variance is negative (a covariance broken by rounding)."""
    variance = np.diag(covariance)[:3]
    rotation = np.degrees(np.sqrt(np.where(variance >= 0, variance, np.nan)))
    translation = np.linalg.eigvalsh((covariance[3:, 3:] + covariance[3:, 3:].T) / 2)
    return bool(np.all(rotation <= least[0]) and np.sqrt(max(translation[1], 0.0)) <= least[1])


def with_unobservable(covariance: np.ndarray, unobservable: np.ndarray) -> np.ndarray:
    """``covariance`` (6, 6) with :data:`UNINFORMED` variance along the ``unobservable`` (n, 3) unit translation
    directions (where a bundle adjustment's covariance has none)."""
    out = covariance.copy()
    out[3:, 3:] += UNINFORMED * unobservable.T @ unobservable
    return out


def _information(covariance: np.ndarray, void: float = 0.0) -> np.ndarray:
    """The inverse (6, 6) of the symmetric ``covariance`` on its positive eigen-directions; ``void`` on the others
    (their variance broken by rounding, or none: not a measurement), so that no direction is ever claimed exact
    (a pseudo-inverse gives a null direction of an information a variance of 0). Also the way back, information
    to covariance with ``void`` = :data:`UNINFORMED`."""
    lam, V = np.linalg.eigh((covariance + covariance.T) / 2)
    positive = lam > 1e-12 * max(float(lam.max()), 1e-300)
    return (V * np.where(positive, 1 / np.where(positive, lam, 1.0), void)) @ V.T
