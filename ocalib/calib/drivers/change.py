"""A change of a camera's extrinsic told from noise, on the hand-eye residuals of the on-line head's input.

Each frame's motion pair (camera 0's motion ``A``, camera k's ``B``, consecutive frames) gives the residuals of
``A X = X B`` under one estimate of the head's, ``X = (R, t)`` and ``s``, taken once it has settled:
``r = (rotvec(R_A R R_B^T R^T), (R_A - I) t + t_A - s R t_B)`` (6,). A step of the truth from there,
``d = (d_rot, d_t, d_s)``, shows as ``r = J d`` (first order), ``J = [[I - R_A, 0, 0], [-s [R t_B]x, I - R_A, R t_B]]``.
Each frame tests a two-sample generalized likelihood ratio: do the last ``windows`` frames take another step than
the ``history`` before them? With the rows weighed by the inverse covariance of the history's residuals (once its own
step is fitted), the ratio is chi-square with rank(H) degrees of freedom while nothing changed; it is divided by
its overdispersion (the median ratio of the earlier tests over the chi-square median, at least 1: the residuals are
neither white nor Gaussian). A p-value under ``false_alarm`` on ``persistence`` frames in a row is a change; its
first frame is the split of the window that explains it best. Fitting each side's own step absorbs a lasting error
of the reference estimate.

Convention: ``T_cam0_camk`` (``p_cam0 = R p_camk + t``, camera-0 units), ``s`` camera-k units into camera-0 units;
poses camera-to-world; a step ``d`` = (rotation rad, translation, scale) with its vectors in camera 0's axes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import chi2 as chi2_distribution

from ocalib.geometry.pose import cross_matrix

SEGMENT_HISTORIES = 10  # the frames a segment tests, in histories (a new reference each; segments overlap by a span)
OUTLIER_LEVEL = 1e-4  # a frame's residuals beyond this chi-square level weigh less (:func:`_outlier_weights`)


@dataclass
class Change:
    """A detected change: the first ``frame`` that disagreed, the ``detected`` frame, and the step from the old
    extrinsic to the new (rotation deg, translation in camera-0 units)."""

    frame: int
    detected: int
    rotation_change_deg: float
    translation_change: float


@dataclass(frozen=True)
class ChangeTest:
    """The test's settings: the ``windows`` tested at every frame (windows of 100 and 300 frames notice small changes
    in much noise, but raise alarms over the slow drift of a long stream's residuals), the chance of a false alarm per
    frame, frames in a row over the threshold
    (``persistence``), frames before the first test (``warmup``: the estimate settles, and from then on until the
    head's rotation 1-sigma is under ``settled_deg`` about every axis: its estimate is the residuals' reference, and
    one degrees off breaks their first-order model), the frames before a window that it is compared with
    (``history``, at least ``min_history``)."""

    windows: tuple[int, ...] = (30,)
    false_alarm: float = 1e-6
    persistence: int = 3
    warmup: int = 60
    history: int = 300
    min_history: int = 120
    settled_deg: float = 0.5


def handeye_residuals(
    A: np.ndarray, B: np.ndarray, R: np.ndarray, t: np.ndarray, s: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The residuals (T, 6) of motions ``A``, ``B`` (T, 4, 4) under extrinsics ``R`` (T, 3, 3), ``t`` (T, 3) and
    scales ``s`` (T,), and their Jacobians (T, 6, 7) with respect to a step of the
    extrinsic and the scale (see the module)."""
    RA, tA = A[:, :3, :3], A[:, :3, 3]
    rotation = Rotation.from_matrix(RA @ R @ B[:, :3, :3].mT @ R.mT).as_rotvec()
    moved = np.einsum("tij,tj->ti", R, B[:, :3, 3])  # camera k's translation in camera 0's axes
    translation = np.einsum("tij,tj->ti", RA - np.eye(3), t) + tA - s[:, None] * moved
    J = np.zeros((len(A), 6, 7))
    J[:, :3, :3] = J[:, 3:, 3:6] = np.eye(3) - RA
    J[:, 3:, :3] = -s[:, None, None] * cross_matrix(moved)
    J[:, 3:, 6] = moved
    return np.concatenate([rotation, translation], 1), J


def motions(poses: np.ndarray) -> np.ndarray:
    """Consecutive motions (T, 4, 4) of poses (T, 4, 4) camera-to-world; the first is the identity."""
    out = np.broadcast_to(np.eye(4), poses.shape).copy()
    out[1:] = np.linalg.inv(poses[:-1]) @ poses[1:]
    return out


def first_change(
    poses0: np.ndarray,
    posesk: np.ndarray,
    R: np.ndarray,
    t: np.ndarray,
    s: np.ndarray,
    test: ChangeTest = ChangeTest(),
    rotation_std: np.ndarray | None = None,
) -> Change | None:
    """The first change of camera k's extrinsic in a stream, or None.

    poses0, posesk: (T, 4, 4) camera-to-world poses of camera 0 and camera k (NaN where invalid).
    R, t, s: (T, 3, 3), (T, 3), (T,) the head's estimate after each frame; ``rotation_std`` (T, 3) its rotation's
    1-sigma (deg; None: settled from the start). The stream is tested in overlapping segments; each segment's
    residuals are taken against the estimate after its first ``test.warmup`` frames, or the first one after them whose
    rotation is settled (the head's estimate moves, and the first-order model holds near its reference), and it tests
    the frames after a full history, the first segment from its reference on.
    """
    settled = np.ones(len(R), bool) if rotation_std is None else (rotation_std <= test.settled_deg).all(1)
    span = test.warmup + test.history + max(test.windows)  # the frames before the first one a later segment tests
    stride = SEGMENT_HISTORIES * test.history
    for start in range(0, max(len(poses0) - span, 0) + 1, stride):
        part = slice(start, start + span + stride)
        first = 0 if start == 0 else span - test.persistence
        found = _segment_change(poses0[part], posesk[part], R[part], t[part], s[part], settled[part], test, first)
        if found is not None:
            return Change(found.frame + start, found.detected + start, found.rotation_change_deg,
                          found.translation_change)  # fmt: skip
    return None


def _segment_change(poses0, posesk, R, t, s, settled, test: ChangeTest, first: int) -> Change | None:
    """:func:`first_change` within one segment, counting only detections at frame ``first`` or later."""
    frames, sums = _referenced_sums(poses0, posesk, R, t, s, test.warmup, settled, test.min_history)
    p = np.ones((len(test.windows), len(frames) + 1))  # per window and end: the p-value (Bonferroni over windows)
    for i, W in enumerate(test.windows):
        ends = np.arange(W + test.min_history, len(frames) + 1)  # window [end - W, end), history before it
        if len(ends):
            ratio, dof, _ = _split_ratio(sums, np.maximum(ends - W - test.history, 0), ends - W, ends)
            ratio = ratio / _dispersion(ratio / chi2_distribution.median(dof), W)
            p[i, ends] = np.minimum(chi2_distribution.sf(ratio, dof) * len(test.windows), 1)
    over = np.convolve(p.min(0) < test.false_alarm, np.ones(test.persistence), "valid")
    hits = [h + test.persistence - 1 for h in np.flatnonzero(over >= test.persistence)]
    end = next((e for e in hits if frames[e - 1] >= first), None)
    if end is None:
        return None
    splits = np.arange(end - test.windows[int(np.argmin(p[:, end]))], end)
    ratio, _, step = _split_ratio(sums, np.maximum(splits - test.history, 0), splits, np.full_like(splits, end))
    best = int(np.argmax(ratio))
    return Change(int(frames[splits[best]]), int(frames[end - 1]), float(np.degrees(np.linalg.norm(step[best, :3]))),
                  float(np.linalg.norm(step[best, 3:])))  # fmt: skip


def _referenced_sums(
    poses0, posesk, R, t, s, warmup: int, settled, min_history: int
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The frames (n,) tested, from the reference on, and the running sums of their residuals (:func:`_cumulative`,
    each frame weighed against glitches: :func:`_outlier_weights` from the first ``min_history``), all taken against
    the estimate of the reference frame (a fixed one: the head's estimate moves): frame ``warmup - 1`` or the first
    after it that is ``settled`` (T,) bool."""
    A, B = motions(poses0)[1:], motions(posesk)[1:]
    candidates = np.flatnonzero(settled[min(warmup, len(R)) - 1 :]) + min(warmup, len(R)) - 1
    ref = int(candidates[0]) if len(candidates) else len(R) - 1
    valid = np.isfinite(A).all((1, 2)) & np.isfinite(B).all((1, 2)) & (np.arange(len(A)) >= ref)
    if not (len(candidates) and np.isfinite(R[ref]).all() and np.isfinite(t[ref]).all() and np.isfinite(s[ref])):
        valid[:] = False
    reference = (np.broadcast_to(x[ref], (int(valid.sum()), *x.shape[1:])) for x in (R, t, s))
    r, J = handeye_residuals(A[valid], B[valid], *reference)
    w = np.sqrt(_outlier_weights(r, min_history))[:, None]
    return np.flatnonzero(valid) + 1, _cumulative(r * w, J * w[..., None])


def _outlier_weights(r: np.ndarray, first: int) -> np.ndarray:
    """Each frame's weight (n,) against a glitch of the pose source (a VIO relocalisation or jump: one frame's
    motions off by far more than the noise): ``min(1, c^2 / m)`` with ``m`` the frame's residual ``r`` (n, 6) squared
    in the metric of the ``first`` frames' second moment (itself without their own outliers), ``c^2`` the chi-square
    quantile at ``OUTLIER_LEVEL`` with 6 degrees of freedom. One frame then adds at most ``c^2`` to a likelihood ratio,
    under a test's threshold; a lasting step still adds up over the frames after it."""
    c2 = chi2_distribution.isf(OUTLIER_LEVEL, 6)
    head = r[:first]
    if len(head) < 12:
        return np.ones(len(r))
    for _ in range(2):  # the second moment, then again without the frames it calls outliers
        try:
            m = np.einsum("ti,ij,tj->t", r, np.linalg.pinv(head.T @ head / len(head), hermitian=True), r)
        except np.linalg.LinAlgError:
            return np.ones(len(r))
        head = r[:first][m[:first] <= c2]
    return np.minimum(1.0, c2 / np.maximum(m, 1e-300))


def _cumulative(r: np.ndarray, J: np.ndarray) -> dict[str, np.ndarray]:
    """Running sums (n + 1, ...) over the frames' residuals r (n, 6) and Jacobians J (n, 6, 7): ``JJ`` (6, 7, 6, 7)
    of J_ai J_bj, ``rJ`` (6, 6, 7) of r_a J_bj, ``rr`` (6, 6) of r_a r_b, and the count ``n``."""
    terms = {
        "JJ": np.einsum("nai,nbj->naibj", J, J),
        "rJ": np.einsum("na,nbj->nabj", r, J),
        "rr": np.einsum("na,nb->nab", r, r),
        "n": np.ones(len(r)),
    }
    return {k: np.concatenate([np.zeros((1, *v.shape[1:])), np.cumsum(v, 0)]) for k, v in terms.items()}


def _split_ratio(sums: dict, a: np.ndarray, b: np.ndarray, c: np.ndarray):
    """The likelihood ratio (E,) that frames [b, c) take another step of the extrinsic than frames [a, b), with its
    degrees of freedom (E,) and the step (E, 7) between the two; the rows weighed by the inverse covariance of
    [a, b)'s residuals once its own step is taken out (which absorbs a lasting error of the head's estimate)."""
    part = lambda key, i, j: sums[key][j] - sums[key][i]  # noqa: E731
    JJ, rJ, rr, n = part("JJ", a, b), part("rJ", a, b), part("rr", a, b), part("n", a, b)
    fit = _solve(np.einsum("eaiaj->eij", JJ), np.einsum("eaai->ei", rJ))  # least squares, unweighted
    Jfit = np.einsum("eaibj,ej->eaib", JJ, fit)
    cross = np.einsum("eabj,ej->eab", rJ, fit)
    covariance = (rr - cross - cross.mT + np.einsum("eaib,ei->eab", Jfit, fit)) / n[:, None, None]
    weight = np.linalg.pinv(covariance, rcond=1e-10, hermitian=True)
    info = lambda i, j: np.einsum("eab,eaibj->eij", weight, part("JJ", i, j))  # noqa: E731
    grad = lambda i, j: np.einsum("eab,ebaj->ej", weight, part("rJ", i, j))  # noqa: E731
    H0, g0, H1, g1 = info(a, b), grad(a, b), info(b, c), grad(b, c)
    step0, step1, both = _solve(H0, g0), _solve(H1, g1), _solve(H0 + H1, g0 + g1)
    ratio = (g0 * step0).sum(1) + (g1 * step1).sum(1) - ((g0 + g1) * both).sum(1)
    dof = np.linalg.matrix_rank(H1, rtol=1e-8, hermitian=True)
    return ratio, np.maximum(dof, 1), step1 - step0


def _dispersion(relative: np.ndarray, lag: int) -> np.ndarray:
    """Each test's overdispersion (E,): the median of the ``relative`` ratios (E,) (ratio over its chi-square median)
    of the tests that ended ``lag`` to ``2 lag`` or more tests before it (updated every ``lag`` tests), at least 1 (1
    where there are none)."""
    out = np.ones(len(relative))
    for e in range(2 * lag, len(relative), lag):
        out[e : e + lag] = max(float(np.median(relative[: e - lag])), 1.0)
    return out


def _solve(H: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Least-squares steps (E, 7) of normal equations H (E, 7, 7), g (E, 7), where H may be singular."""
    return np.einsum("eij,ej->ei", np.linalg.pinv(H, rcond=1e-8, hermitian=True), g)


def step_size(R0: np.ndarray, t0: np.ndarray, R1: np.ndarray, t1: np.ndarray) -> tuple[float, float]:
    """The step from extrinsic (R0 (3, 3), t0 (3,)) to (R1, t1): rotation angle (deg) and translation distance."""
    angle = np.linalg.norm(Rotation.from_matrix(R1 @ R0.T).as_rotvec())
    return float(np.degrees(angle)), float(np.linalg.norm(t1 - t0))
