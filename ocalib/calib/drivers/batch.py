"""Batch reference solver (Esquivel et al. 2007): the same hand-eye equations, all frames at once.

Used by the tests as the reference of the on-line solvers and by ``--solver batch``. No gating and no
robust weights: every valid motion pair counts once. The closed form is the SVD of all stacked rotation
blocks, then least squares on all stacked translation rows; the refinement minimises the weighted sum of
both residuals over all rows at once with Levenberg-Marquardt (forward-mode autograd Jacobians), independently of the
moment-based refinement of :mod:`ocalib.calib.stages.refine` that the on-line solver runs.

Convention: as :mod:`ocalib.calib.drivers.online` -- poses (T, C, 4, 4) camera-to-world, camera 0 the reference.
"""

from __future__ import annotations

import torch
from torch import Tensor

from ocalib.calib.stages.handeye import pair_features, rotation_block, translation_rows
from ocalib.calib.stages.pairing import MOTIONS, gap_weights
from ocalib.calib.stages.rotation import batch_rotation, planar_motion, rotation_observable
from ocalib.calib.stages.translation import SCALE_FITS, symmetric_scale
from ocalib.geometry.pose import invert_pose
from ocalib.geometry.quaternion import quaternion_multiply, quaternion_to_rotation_matrix, rotation_matrix_to_quaternion


def motion_pairs(num_frames: int, motion: str | tuple[int, ...]) -> tuple[Tensor, Tensor, Tensor]:
    """Frame indices (start, end) of every motion pair of a sequence, in the order the on-line solver
    meets them (by end frame), and the index of each pair's gap in the pairing. Gap 0 stands for the pair
    with frame 0."""
    gaps = MOTIONS[motion] if isinstance(motion, str) else tuple(motion)
    start, end, gap = [], [], []
    for t in range(num_frames):
        for i, g in enumerate(gaps):
            if (g > 0 and t - g >= 0) or (g == 0 and t > 0):
                start.append(t - g if g > 0 else 0)
                end.append(t)
                gap.append(i)
    return tuple(torch.tensor(x, dtype=torch.long) for x in (start, end, gap))


def pair_motions(poses: Tensor, start: Tensor, end: Tensor) -> Tensor:
    """Motions ``T_start^-1 T_end`` (M, C, 4, 4) of every camera for pairs of frame indices (M,)."""
    return invert_pose(poses[start]) @ poses[end]


def batch_calibrate(
    poses: Tensor,
    motion: str | tuple[int, ...] = "multi",
    symmetric: bool = True,
    refine: bool = True,
    scale_fit: str = "symmetric",
) -> dict[str, Tensor]:
    """Batch hand-eye calibration of cameras 1..C-1 against camera 0.

    Args:
        poses: (T, C, 4, 4) camera-to-world poses, float64, all valid.
        motion: the motion pairing (see :data:`ocalib.calib.drivers.online.MOTIONS`).
        symmetric: translation rows of each pair in both directions (see :mod:`ocalib.calib.stages.handeye`).
        refine: refine rotation, translation and scale jointly (where rotation is observable and the motion
            not planar); else the closed form.
        scale_fit: ``"symmetric"``: the scale re-fitted at the final rotation with no preferred camera (as the
            on-line head's, :func:`~ocalib.calib.stages.translation.symmetric_scale`); ``"regression"``: least squares'.

    Returns:
        ``quaternion`` (K, 4), ``rotation`` (K, 3, 3), ``translation`` (K, 3), ``scale`` (K,),
        ``singular_values`` (K, 4), ``refined`` (K,) bool, and the stacked ``blocks`` (K, M, 4, 4) and
        ``features`` (K, M D, 15) (D = 2 if symmetric).
    """
    if scale_fit not in SCALE_FITS:
        raise ValueError(f"scale_fit must be one of {SCALE_FITS}, got {scale_fit!r}")
    start, end, gap = motion_pairs(poses.shape[0], motion)
    m = pair_motions(poses, start, end)  # (M, C, 4, 4)
    q = rotation_matrix_to_quaternion(m[..., :3, :3])
    q0, q1 = q[:, :1].expand_as(q[:, 1:]), q[:, 1:]
    A = rotation_block(q0, q1).transpose(0, 1)  # (K, M, 4, 4)
    w = _pair_weights(A, gap)  # (K, M)
    quat, S, _ = batch_rotation(A, w)
    dR = quaternion_to_rotation_matrix(quat)
    z = pair_features(m[:, :1].expand_as(m[:, 1:]), m[:, 1:], symmetric).transpose(0, 1).flatten(1, 2)  # (K, MD, 15)
    R0, t0, t1 = z[..., :9].unflatten(-1, (3, 3)), z[..., 12:], z[..., 9:12]
    R0 = torch.eye(3, dtype=R0.dtype) - R0
    sw = w.sqrt().repeat_interleave(z.shape[1] // len(start), 1)[..., None]  # each pair's D rows
    B, b = _weighted_rows(R0, t0, t1, dR, sw)
    x = (torch.linalg.pinv(B) @ b.unsqueeze(-1)).squeeze(-1)
    refined = torch.zeros(len(quat), dtype=torch.bool)
    if refine:
        pairs = w.sum(-1)
        refined = rotation_observable(S, pairs) & ~planar_motion(S, pairs) & (pairs >= 3)
        for k in torch.nonzero(refined).flatten().tolist():
            for _ in range(2):  # weighted by the closed form's residual variances, then by those of the first solve
                quat[k], x[k] = _refine(w[k].sqrt()[:, None, None] * A[k], R0[k], t0[k], t1[k], sw[k], quat[k], x[k],
                                        float(pairs[k]), 2 if symmetric else 1)  # fmt: skip
        dR = quaternion_to_rotation_matrix(quat)
    if scale_fit == "symmetric":
        B, b = _weighted_rows(R0, t0, t1, dR, sw)
        x = symmetric_scale(B.mT @ B, (B.mT @ b.unsqueeze(-1)).squeeze(-1), b.square().sum(-1), x)
    return {
        "quaternion": quat,
        "rotation": dR,
        "translation": x[:, :3],
        "scale": x[:, 3],
        "singular_values": S,
        "refined": refined,
        "blocks": A,
        "features": z,
    }


def _weighted_rows(R0: Tensor, t0: Tensor, t1: Tensor, dR: Tensor, row_weight: Tensor) -> tuple[Tensor, Tensor]:
    """The translation rows at the rotation ``dR`` (K, 3, 3), each pair's times ``row_weight`` (K, MD, 1):
    ``B`` (K, 3MD, 4), ``b`` (K, 3MD)."""
    B, b = translation_rows(R0, t0, t1, dR.unsqueeze(1))
    return (row_weight[..., None] * B).flatten(1, 2), (row_weight * b).flatten(1, 2)


def _pair_weights(A: Tensor, gap: Tensor) -> Tensor:
    """Each pair's weight (K, M): its gap's :func:`~ocalib.calib.stages.pairing.gap_weights`, from the SVD of that
    gap's blocks alone (A: (K, M, 4, 4), gap: (M,) gap indices)."""
    present = gap.unique()
    S2 = torch.stack([torch.linalg.svdvals(A[:, gap == g].flatten(1, 2)).square() for g in present], 1)  # (K, G, 4)
    rows = torch.stack([(gap == g).sum() for g in present]).to(A.dtype).expand(S2.shape[:2])
    w = gap_weights(S2, rows) if len(present) > 1 else torch.ones_like(rows)
    return w[:, torch.searchsorted(present, gap)]


def _refine(
    A, R0, t0, t1, row_weight, quat, x, pairs: float, groups: int = 1, iterations: int = 100
) -> tuple[Tensor, Tensor]:
    """Levenberg-Marquardt on all rows from ``(quat, x)``: rotation rows ``A q`` (M, 4, 4) (weighted) and translation
    rows ``(I - R0) dT + s dR t1 - t0`` (N, ...), each times ``row_weight`` (N, 1), in ``groups`` interleaved groups
    (pair by pair: a pair's rows in each direction), weighted by their residual variances at ``(quat, x)`` (``2 M - 3``
    and ``3 M - 4`` degrees of freedom for M motion pairs, for each group). -> (quat (4,), x (4,))."""
    eye = torch.eye(3, dtype=quat.dtype)

    def rows(theta, q0, x):  # theta: rotation vector applied on the right of q0
        half = theta.norm() / 2
        dq = torch.cat([torch.cos(half).reshape(1), torch.sinc(half / torch.pi) * theta / 2])
        q = quaternion_multiply(q0, dq)
        dR = quaternion_to_rotation_matrix(q)
        rot = (A @ q).flatten()
        trans = (row_weight * ((eye - R0) @ x[:3] + x[3] * (dR @ t1.unsqueeze(-1)).squeeze(-1) - t0)).flatten()
        return rot, trans

    zero = torch.zeros(3, dtype=quat.dtype)
    rot, trans = rows(zero, quat, x)
    wr = (2 * pairs - 3) / rot.square().sum()
    wt = (3 * pairs - 4) / trans.view(-1, groups, 3).square().sum((0, 2)) / groups  # (groups,): a pair's share

    def residual(p):
        rot, trans = rows(p[:3], quat, p[3:])
        return torch.cat([wr.sqrt() * rot, (wt.sqrt()[:, None] * trans.view(-1, groups, 3)).flatten()])

    p = torch.cat([zero, x])
    cost, mu = residual(p).square().sum(), 1e-6
    for _ in range(iterations):
        r = residual(p)
        J = torch.func.jacfwd(residual)(p)
        H, g = J.T @ J, J.T @ r
        step = -torch.linalg.solve(H + mu * torch.diag(H.diagonal()), g)
        new = residual(p + step).square().sum()
        if new <= cost:
            p, cost, mu = p + step, new, mu / 10
            if step.abs().max() < 1e-13 * (1 + p.abs().max()):
                break
        else:
            mu *= 10
    half = p[:3].norm() / 2
    q = quaternion_multiply(quat, torch.cat([torch.cos(half).reshape(1), torch.sinc(half / torch.pi) * p[:3] / 2]))
    q = torch.where(q[0] < 0, -q, q)
    return q / q.norm(), p[3:]
