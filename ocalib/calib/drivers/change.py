"""A change of a camera's extrinsic told from noise, on the hand-eye residuals of the on-line head's input.

Each frame's motion pair (camera 0's motion ``A``, camera k's ``B``, from ``gap`` frames before: consecutive ones by
default) gives the residuals of
``A X = X B`` under one estimate of the head's, ``X = (R, t)`` and ``s``, taken once it has settled:
``r = (rotvec(R_A R R_B^T R^T), (R_A - I) t + t_A - s R t_B)`` (6,). A step of the truth from there,
``d = (d_rot, d_t, d_s)``, shows as ``r = J d`` (first order), ``J = [[I - R_A, 0, 0], [-s [R t_B]x, I - R_A, R t_B]]``.
Each frame tests a two-sample generalized likelihood ratio: do the last ``windows`` frames take another step than
the ``history`` before them? With the rows weighed by the inverse covariance of the history's residuals (once its own
step is fitted), the ratio is chi-square with rank(H) degrees of freedom while nothing changed; it is divided by
its overdispersion (the median ratio of the earlier tests over the chi-square median, at least 1: the residuals are
neither white nor Gaussian); tests over shorter histories than ``min_history`` (from one window on) decide nothing
but give the first decisions theirs. A p-value under ``false_alarm`` on ``persistence`` frames in a row is a change;
its first frame is the split of the window that explains it best. Fitting each side's own step absorbs a lasting
error of the reference estimate.

Convention: ``T_cam0_camk`` (``p_cam0 = R p_camk + t``, camera-0 units), ``s`` camera-k units into camera-0 units;
poses camera-to-world; a step ``d`` = (rotation rad, translation, scale) with its vectors in camera 0's axes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.special import chdtrc, chdtri, gammaincinv

from ocalib.geometry.se3 import cross_matrix, rotation_angle_deg

SEGMENT_HISTORIES = 10  # the frames a segment tests, in histories (a new reference each; segments overlap by a span)
OUTLIER_LEVEL = 1e-4  # a frame's residuals beyond this chi-square level weigh less (:func:`_outlier_weights`)
SPLIT_CHUNK = 256  # tests :func:`_split_ratio` computes together (their arrays stay in the processor's cache)


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
    (``history``, at least ``min_history``), and the ``gap`` of the motion pairs (1: consecutive frames; a longer
    gap sees a slowly turning path's knock where each pose's error is its own, but its overlapping pairs' residuals
    are correlated and the test is not calibrated where errors accumulate: docs/results-change.md)."""

    windows: tuple[int, ...] = (30,)
    false_alarm: float = 1e-6
    persistence: int = 3
    warmup: int = 60
    history: int = 300
    min_history: int = 120
    settled_deg: float = 0.5
    gap: int = 1

    def __post_init__(self):
        if self.gap < 1:
            raise ValueError(f"the change test's gap must be at least 1 frame, got {self.gap}")

    def first_decision(self, reference: int) -> int:
        """The first frame a test can decide at, its residuals referenced at frame ``reference``: a full window after
        ``min_history`` frames, and two windows of tests before it that give its overdispersion (:func:`_dispersion`;
        those from a history of one window on)."""
        return reference + self.gap + max(self.min_history + max(self.windows), 4 * max(self.windows)) - 1


def handeye_residuals(
    A: np.ndarray, B: np.ndarray, R: np.ndarray, t: np.ndarray, s: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The residuals (T, 6) of motions ``A``, ``B`` (T, 4, 4) under extrinsics ``R`` (T, 3, 3), ``t`` (T, 3) and
    scales ``s`` (T,), and their Jacobians (T, 6, 7) with respect to a step of the
    extrinsic and the scale (see the module)."""
    r, turn, moved = _residuals(A, B, R, t, s)
    J = np.zeros((len(A), 6, 7))
    J[:, :3, :3] = J[:, 3:, 3:6] = turn
    J[:, 3:, :3] = -s[:, None, None] * cross_matrix(moved)
    J[:, 3:, 6] = moved
    return r, J


def _residuals(A, B, R, t, s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`handeye_residuals`' residuals (T, 6) and the two factors of its Jacobians: ``I - R_A`` (T, 3, 3) and
    ``R t_B`` (T, 3), camera k's translation in camera 0's axes."""
    RA, tA = A[:, :3, :3], A[:, :3, 3]
    rotation = Rotation.from_matrix(RA @ R @ B[:, :3, :3].mT @ R.mT).as_rotvec()
    moved = np.einsum("tij,tj->ti", R, B[:, :3, 3])
    translation = np.einsum("tij,tj->ti", RA - np.eye(3), t) + tA - s[:, None] * moved
    return np.concatenate([rotation, translation], 1), np.eye(3) - RA, moved


def jacobian_basis(s: float) -> np.ndarray:
    """The basis (12, 6, 7) in which :func:`handeye_residuals`' Jacobian at one scale ``s`` has 12 coefficients:
    ``J = sum_k q_k basis[k]`` with ``q = (I - R_A`` row-major (9), ``R t_B`` (3)): the running sums of
    :func:`_cumulative` then hold 18 x 18 numbers a frame instead of J's 42 x 42 and more."""
    basis = np.zeros((12, 6, 7))
    for k, (i, j) in enumerate(np.ndindex(3, 3)):
        basis[k, i, j] = basis[k, 3 + i, 3 + j] = 1.0
    basis[9:, 3:, :3] = -s * cross_matrix(np.eye(3))
    basis[9:, 3:, 6] = np.eye(3)
    return basis


def motions(poses: np.ndarray, gap: int = 1) -> np.ndarray:
    """The motions (T, 4, 4) of poses (T, 4, 4) camera-to-world from ``gap`` frames before to each frame; the first
    ``gap`` are the identity."""
    out = np.broadcast_to(np.eye(4), poses.shape).copy()
    out[gap:] = np.linalg.inv(poses[:-gap]) @ poses[gap:]
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
    frames, sums = _referenced_sums(poses0, posesk, R, t, s, test, settled)
    p = np.ones((len(test.windows), len(frames) + 1))  # per window and end: the p-value (Bonferroni over windows)
    for i, W in enumerate(test.windows):
        # window [end - W, end), history before it; those with under min_history of it only learn the overdispersion
        ends = np.arange(2 * W, len(frames) + 1)
        if len(ends):
            ratio, dof, _ = _split_ratio(sums, np.maximum(ends - W - test.history, 0), ends - W, ends)
            ratio = ratio / _dispersion(ratio / chi2_median(dof), W)
            decide = ends >= W + test.min_history
            p[i, ends[decide]] = np.minimum(chi2_sf(ratio[decide], dof[decide]) * len(test.windows), 1)
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


def _referenced_sums(poses0, posesk, R, t, s, test: ChangeTest, settled) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The frames (n,) tested, from the reference on, and the running sums of their residuals (:func:`_cumulative`,
    each frame weighed against glitches: :func:`_outlier_weights` from the first ``min_history``), all taken against
    the estimate of the reference frame (a fixed one: the head's estimate moves): frame ``warmup - 1`` or the first
    after it that is ``settled`` (T,) bool."""
    warmup, min_history, gap = test.warmup, test.min_history, test.gap
    A, B = motions(poses0, gap)[gap:], motions(posesk, gap)[gap:]
    candidates = np.flatnonzero(settled[min(warmup, len(R)) - 1 :]) + min(warmup, len(R)) - 1
    ref = int(candidates[0]) if len(candidates) else len(R) - 1
    valid = np.isfinite(A).all((1, 2)) & np.isfinite(B).all((1, 2)) & (np.arange(len(A)) >= ref)
    if not (len(candidates) and np.isfinite(R[ref]).all() and np.isfinite(t[ref]).all() and np.isfinite(s[ref])):
        valid[:] = False
    reference = (np.broadcast_to(x[ref], (int(valid.sum()), *x.shape[1:])) for x in (R, t, s))
    r, turn, moved = _residuals(A[valid], B[valid], *reference)
    w = np.sqrt(_outlier_weights(r, min_history))[:, None]
    coefficients = np.concatenate([turn.reshape(-1, 9), moved], 1)  # the Jacobians in jacobian_basis(s[ref])
    return np.flatnonzero(valid) + gap, _cumulative(r * w, coefficients * w, jacobian_basis(float(s[ref])))


def _outlier_weights(r: np.ndarray, first: int) -> np.ndarray:
    """Each frame's weight (n,) against a glitch of the pose source (a VIO relocalisation or jump: one frame's
    motions off by far more than the noise): ``min(1, c^2 / m)`` with ``m`` the frame's residual ``r`` (n, 6) squared
    in the metric of the ``first`` frames' second moment (itself without their own outliers), ``c^2`` the chi-square
    quantile at ``OUTLIER_LEVEL`` with 6 degrees of freedom. One frame then adds at most ``c^2`` to a likelihood ratio,
    under a test's threshold; a lasting step still adds up over the frames after it."""
    c2 = float(chdtri(6, OUTLIER_LEVEL))  # the chi-square's upper OUTLIER_LEVEL quantile
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


def _cumulative(r: np.ndarray, J: np.ndarray, basis: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Running sums (n + 1, ...) over the frames' residuals r (n, 6) and Jacobians J (n, 6, 7), or with ``basis``
    (d, 6, 7) J's coefficients (n, d) in it (``J_t = sum_k J[t, k] basis[k]``, :func:`jacobian_basis`): ``uu``
    (n + 1, d + 6, d + 6) of ``u u^T`` with ``u = (coefficients, r)`` (every product of two Jacobian entries, of an
    entry and a residual, and of two residuals, in O(d^2) a frame), the count ``n``; and ``basis`` (without one: the
    42 entries of J)."""
    if basis is None:
        basis, J = np.eye(42).reshape(42, 6, 7), J.reshape(len(J), 42)
    u = np.concatenate([J, r], 1)
    uu = np.zeros((len(u) + 1, u.shape[1], u.shape[1]))
    np.cumsum(u[:, :, None] * u[:, None, :], 0, out=uu[1:])
    return {"uu": uu, "n": np.arange(len(u) + 1, dtype=float), "basis": basis}


def _split_ratio(sums: dict, a: np.ndarray, b: np.ndarray, c: np.ndarray):
    """The likelihood ratio (E,) that frames [b, c) take another step of the extrinsic than frames [a, b), with its
    degrees of freedom (E,) and the step (E, 7) between the two; the rows weighed by the inverse covariance of
    [a, b)'s residuals once its own step is taken out (which absorbs a lasting error of the head's estimate). From
    :func:`_cumulative`'s sums, O(1) per test whatever the lengths of the two parts; ``SPLIT_CHUNK`` tests at a time."""
    if len(a) > SPLIT_CHUNK:
        parts = [
            _split_ratio(sums, *(x[i : i + SPLIT_CHUNK] for x in (a, b, c))) for i in range(0, len(a), SPLIT_CHUNK)
        ]
        return tuple(np.concatenate(x) for x in zip(*parts))
    basis = sums["basis"]
    d, E = len(basis), len(a)
    flat = basis.reshape(d * 6, 7)  # rows (k, a): J_ai = sum_k q_k basis[k, a, i]
    before, after = sums["uu"][b] - sums["uu"][a], sums["uu"][c] - sums["uu"][b]
    n = sums["n"][b] - sums["n"][a]
    Q, P, rr = before[:, :d, :d], before[:, :d, d:], before[:, d:, d:]  # sums of q q^T, q r^T, r r^T
    Qt = np.ascontiguousarray(Q.reshape(E, d * d).T)
    rows, columns = _pairing(basis, 0), _pairing(basis, 1)
    H = _contract(Qt, np.eye(6).reshape(36, 1), rows).T.reshape(E, 7, 7)  # sum of J^T J
    fit = _solve(H, P.reshape(E, d * 6) @ flat)[0]  # least squares, unweighted
    fitted = (fit @ flat.T).reshape(E, d, 6)  # basis[k] fit: J fit = sum_k q_k fitted[k]
    cross = np.einsum("eka,ekb->eab", P, fitted)  # sum of r (J fit)^T
    outer = (fit[:, :, None] * fit[:, None, :]).reshape(E, 49).T
    covariance = (rr - cross - cross.mT + _contract(Qt, outer, columns).T.reshape(E, 6, 6)) / n[:, None, None]
    weight = _pinv(covariance, 1e-10)[0]
    Wt = np.ascontiguousarray(weight.reshape(E, 36).T)

    def info(block):  # sum of J^T W J and J^T W r over a block of sums
        Qt = np.ascontiguousarray(block[:, :d, :d].reshape(E, d * d).T)
        g = np.einsum("eka,eab,kbi->ei", block[:, :d, d:], weight, basis, optimize=True)
        return _contract(Qt, Wt, rows).T.reshape(E, 7, 7), g

    (H0, g0), (H1, g1) = info(before), info(after)
    (step0, _), (step1, full), (both, _) = _solve(H0, g0), _solve(H1, g1), _solve(H0 + H1, g0 + g1)
    ratio = (g0 * step0).sum(1) + (g1 * step1).sum(1) - ((g0 + g1) * both).sum(1)
    dof = np.full(E, 7)
    if not full.all():
        dof[~full] = np.linalg.matrix_rank(H1[~full], rtol=1e-8, hermitian=True)
    return ratio, np.maximum(dof, 1), step1 - step0


def _pairing(basis: np.ndarray, over: int) -> tuple:
    """Every pair of nonzero entries ``basis[k, x, y]``, ``basis[l, x', y']`` of a Jacobian basis (d, 6, 7), to sum
    ``sum_kl S_kl basis[k]^T X basis[l]`` (``over`` 0: X (6, 6) between the rows x, x', out (7, 7) by the columns) or
    ``sum_kl S_kl basis[k] X basis[l]^T`` (``over`` 1: X (7, 7) between the columns, out (6, 6)): per pair, the index
    of ``S_kl`` and of the entry of X, the product of the two entries, sorted by the entry of the output they go to;
    then the outputs that have pairs, where each starts, and the size of the output (:func:`_contract`)."""
    k, x, y = np.nonzero(basis)
    v = basis[k, x, y]
    p, q = (z.ravel() for z in np.meshgrid(np.arange(len(k)), np.arange(len(k)), indexing="ij"))
    axes = (x, y) if over == 0 else (y, x)
    inner, outer = basis.shape[1 + over], basis.shape[2 - over]
    into = axes[1][p] * outer + axes[1][q]
    order = np.argsort(into, kind="stable")
    bins, starts = np.unique(into[order], return_index=True)
    X = axes[0][p] * inner + axes[0][q]
    return (k[p] * len(basis) + k[q])[order], X[order], (v[p] * v[q])[order, None], bins, starts, outer * outer


def _contract(St: np.ndarray, Xt: np.ndarray, pairing: tuple) -> np.ndarray:
    """``sum_kl S_kl basis[k]^T X basis[l]`` or its transpose twin (:func:`_pairing`), for sums ``St`` (d * d, E) and
    ``Xt`` (size of X, E or 1), columns the tests: -> (size of the output, E). A sum over the basis's nonzero pairs
    (27 x 27 for :func:`jacobian_basis`), not its dense (d, 6, 7) entries."""
    s, x, v, bins, starts, size = pairing
    out = np.zeros((size, St.shape[1]))
    out[bins] = np.add.reduceat(St[s] * Xt[x] * v, starts, 0)
    return out


def _dispersion(relative: np.ndarray, lag: int) -> np.ndarray:
    """Each test's overdispersion (E,): the median of the ``relative`` ratios (E,) (ratio over its chi-square median)
    of the tests that ended ``lag`` to ``2 lag`` or more tests before it (updated every ``lag`` tests), at least 1;
    infinite where there are none (the first ``2 lag`` tests, which then decide nothing)."""
    out = np.full(len(relative), np.inf)
    for e in range(2 * lag, len(relative), lag):
        out[e : e + lag] = max(float(np.median(relative[: e - lag])), 1.0)
    return out


def _solve(H: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares steps (E, 7) of normal equations H (E, 7, 7), g (E, 7), where H may be singular (the
    pseudo-inverse's, eigenvalues under 1e-8 of the largest cut), and where none is cut (E,) bool (:func:`_pinv`)."""
    inverse, full = _pinv(H, 1e-8)
    return np.einsum("eij,ej->ei", inverse, g), full


def _pinv(H: np.ndarray, rcond: float) -> tuple[np.ndarray, np.ndarray]:
    """Pseudo-inverses (E, n, n) of symmetric positive semi-definite H (E, n, n), eigenvalues under ``rcond`` times
    the largest cut (``np.linalg.pinv(H, rcond, hermitian=True)``), and where none is cut (E,) bool. By Cholesky
    where that is the same matrix: H positive definite with ``trace(H) trace(H^-1) < 1 / (2 rcond)``, a bound on its
    condition number (about six times faster); elsewhere by the eigen-decomposition."""
    E, size = H.shape[:2]
    L, Linv, full = np.zeros_like(H), np.zeros_like(H), np.ones(E, bool)
    with np.errstate(all="ignore"):  # where a pivot is not positive (that matrix by its eigen-decomposition)
        for j in range(size):  # Cholesky, H = L L^T, one column at a time over the batch
            d = H[:, j, j] - (L[:, j, :j] ** 2).sum(1)
            full &= d > 0
            L[:, j, j] = np.sqrt(np.where(full, d, 1.0))
            L[:, j + 1 :, j] = (H[:, j + 1 :, j] - (L[:, j + 1 :, :j] @ L[:, j, :j, None])[..., 0]) / L[:, j, j, None]
        for i in range(size):  # L^-1 by forward substitution
            Linv[:, i, i] = 1 / L[:, i, i]
            Linv[:, i, :i] = -(L[:, i, None, :i] @ Linv[:, :i, :i])[:, 0] / L[:, i, i, None]
        inverse = Linv.mT @ Linv
        full &= np.trace(H, axis1=1, axis2=2) * (Linv**2).sum((1, 2)) * rcond < 0.5
    if not full.all():
        inverse[~full] = np.linalg.pinv(H[~full], rcond=rcond, hermitian=True)
    return inverse, full


def chi2_median(dof: np.ndarray) -> np.ndarray:
    """The chi-square distribution's median with ``dof`` degrees of freedom (scipy.stats' ``chi2.median``, without
    importing scipy.stats)."""
    return 2 * gammaincinv(np.asarray(dof) / 2, 0.5)


def chi2_sf(x: np.ndarray, dof: np.ndarray) -> np.ndarray:
    """The chi-square distribution's survival function (scipy.stats' ``chi2.sf``: 1 at x <= 0)."""
    return chdtrc(dof, np.maximum(x, 0.0))


def step_size(R0: np.ndarray, t0: np.ndarray, R1: np.ndarray, t1: np.ndarray) -> tuple[float, float]:
    """The step from extrinsic (R0 (3, 3), t0 (3,)) to (R1, t1): rotation angle (deg) and translation distance."""
    return float(rotation_angle_deg(R1 @ R0.T)), float(np.linalg.norm(t1 - t0))
