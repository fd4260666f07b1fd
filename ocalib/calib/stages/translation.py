"""Translation and scale of the rig: ``(I - R0) dT + s dR t1 = t0`` for ``x = (dT, s)``.

Two on-line solvers:

* :func:`solve_translation` -- exact: from the O(1) moment ``Z`` (see :mod:`ocalib.calib.stages.handeye`,
  passed as its quadratic form ``(P, p, c)``) it re-solves the normal equations with the current ``dR``
  every frame, so it equals batch least squares at every frame, and early wrong rotations leave no trace.
* :func:`rls_update` -- the paper's recursive least squares with forgetting factor, with the typos of
  the paper corrected (``C <- C / lam - G Gamma^-1 G^T``, minus).

Last, :func:`fit_scale` re-fits the scale at the final rotation with no preferred camera (``scale_fit="symmetric"``,
the default): least squares regresses camera 0's motions on camera k's, so noise on camera k's translations (errors
in the variables) pulls ``s`` toward 0 by camera k's noise-to-signal power, a bias that no number of frames removes
where the motion pairs are short (the head's gaps).

The compiled twins of the exact solve are in :mod:`ocalib.calib.stages.translation_kernel`.

Convention: ``dT`` is in camera 0's frame and units; ``s`` multiplies camera-k units into camera-0 units.
"""

from __future__ import annotations

import torch
from torch import Tensor

from ocalib.calib.stages.handeye import normal_equations, translation_quadratic
from ocalib.calib.stages.linalg import guarded_eigh
from ocalib.calib.stages.rotation import ROTATION_OBSERVABLE_MIN_SV

RANK_TOLERANCE = 1e-9  # eigenvalues below this times the largest are treated as zero
# A translation direction is unobservable with less information than 1e-6 of the best direction's,
# or than the excitation rotation itself needs (``ROTATION_OBSERVABLE_MIN_SV^2``: one 6-degree rotation about an
# axis perpendicular to it, ``(2 sin(3 deg))^2``, or many smaller ones).
UNOBSERVABLE_RELATIVE = 1e-6
UNOBSERVABLE_ABSOLUTE = ROTATION_OBSERVABLE_MIN_SV**2
SCALE_FITS = ("symmetric", "regression")  # how the scale is fitted: see fit_scale


def pinv_solve(H: Tensor, g: Tensor) -> tuple[Tensor, Tensor]:
    """Minimum-norm solution of ``H x = g`` for symmetric PSD ``H`` (..., n, n); also returns ``H^+``."""
    evals, evecs = guarded_eigh(H)
    keep = evals > RANK_TOLERANCE * evals[..., -1:].clamp_min(1e-300)
    inv = torch.where(keep, 1 / torch.where(keep, evals, 1.0), 0.0)
    H_pinv = (evecs * inv.unsqueeze(-2)) @ evecs.mT
    return (H_pinv @ g.unsqueeze(-1)).squeeze(-1), H_pinv


def solve_translation(quadratic: tuple[Tensor, Tensor, Tensor], dR: Tensor) -> Tensor:
    """Exact least-squares ``x = (dT, s)`` (..., 4) with the current rotation ``dR`` (..., 3, 3), from the
    moment's quadratic form (:func:`~ocalib.calib.stages.handeye.translation_quadratic`)."""
    H, g, _ = normal_equations(quadratic, dR.unsqueeze(-3))
    return pinv_solve(H, g)[0]


def symmetric_scale(H: Tensor, g: Tensor, c: Tensor, x: Tensor) -> Tensor:
    """The scale fitted with no preferred camera, and the translation at that scale: ``x = (dT, s)`` (..., 4).

    ``H`` (..., 4, 4), ``g`` (..., 4), ``c`` (...) are the normal equations of the translation rows at the current
    rotation (:func:`~ocalib.calib.stages.handeye.normal_equations`): the residual is ``E(dT, s) = c - 2 x.g + x^T H
    x``. With ``dT`` profiled out (the lever arm ``(I - R0) dT`` fitted away), ``E(s) = A s^2 - 2 B s + C``. Least
    squares gives ``s = B / A``, the regression of camera 0's translations on camera k's: noise on camera k's
    (power ``b1`` against its motion's ``m1``) biases it by ``-b1 / m1`` (errors in the variables), and the reverse
    regression by ``+b0 / m0``. This minimises ``E(s) / s`` instead: ``s = sign(B) sqrt(C / A)``, the geometric mean
    of the two regressions (the ratio of the RMS lengths of the two cameras' lever-arm-free translations): the
    errors-in-variables (Deming) estimate for noise of the same size relative to each camera's motion, unbiased at
    any scale then, and camera 0 against camera k gets the reciprocal scale. Equal to least squares without noise
    (``C = B^2 / A``). ``dT`` is re-solved at that scale. Where the scale is unobservable (``A`` at most
    ``UNOBSERVABLE_RELATIVE`` of ``H_ss``) ``x`` is returned as it is. Kernel twin:
    :func:`ocalib.calib.stages.translation_kernel.symmetric_scale`.
    """
    H_TT, h_Ts, h_ss, g_T, g_s = H[..., :3, :3], H[..., :3, 3], H[..., 3, 3], g[..., :3], g[..., 3]
    _, H_TT_pinv = pinv_solve(H_TT, g_T)
    u = (H_TT_pinv @ h_Ts.unsqueeze(-1)).squeeze(-1)  # dT = v - u s at scale s
    v = (H_TT_pinv @ g_T.unsqueeze(-1)).squeeze(-1)
    A = h_ss - (h_Ts * u).sum(-1)
    B = g_s - (h_Ts * v).sum(-1)
    C = c - (g_T * v).sum(-1)
    ok = A > UNOBSERVABLE_RELATIVE * h_ss
    s = torch.sign(B) * (C.clamp_min(0) / torch.where(ok, A, 1.0)).sqrt()
    fitted = torch.cat([v - u * s.unsqueeze(-1), s.unsqueeze(-1)], -1)
    return torch.where((ok & fitted.isfinite().all(-1)).unsqueeze(-1), fitted, x)


def fit_scale(est: dict[str, Tensor], quadratic: tuple[Tensor, Tensor, Tensor], mode: str = "symmetric") -> dict:
    """The estimate ``est`` (the fields of :func:`~ocalib.calib.stages.solve.closed_form`) with its scale re-fitted at
    its rotation as ``mode`` (one of :data:`SCALE_FITS`) says: ``"symmetric"`` by :func:`symmetric_scale`;
    ``"regression"`` keeps least squares' (the paper's). ``quadratic``: ``(P, p, c)`` of the translation moment. On
    planar motion the translation along the axis stays 0 (unobservable). Kernel twin:
    :func:`ocalib.calib.stages.translation_kernel.fit_scale`."""
    if mode == "regression":
        return est
    x = torch.cat([est["translation"], est["scale"].unsqueeze(-1)], -1)
    x = symmetric_scale(*normal_equations(quadratic, est["rotation"].unsqueeze(-3)), x)
    return {**est, "translation": minimum_norm(x[..., :3], est["planar_axis"]), "scale": x[..., 3]}


def minimum_norm(dT: Tensor, axis: Tensor) -> Tensor:
    """``dT`` (..., 3) less its component along the planar ``axis`` (..., 3; zero where the motion is not planar):
    on planar motion the translation along the rotation axis (a car's height) is unobservable, and the minimum-norm
    value, 0, is reported."""
    return dT - axis * (axis * dT).sum(-1, keepdim=True)


def translation_uncertainty(Z: Tensor, dR: Tensor, x: Tensor, rows: Tensor) -> dict[str, Tensor]:
    """Covariance and information of the translation estimate ``x = (dT, s)`` (..., 4).

    Args:
        Z: (..., 58) the rows' statistics (:func:`~ocalib.calib.stages.handeye.row_statistics`). dR: (..., 3, 3).
        rows: (...) weighted number of motion pairs in ``Z``.

    Returns ``covariance`` (..., 4, 4) (``sigma^2 H^+``, sigma from the residual; infinite with ``3 n <= 4``
    equations, where the residual says nothing), ``information`` (..., 3) with ``directions`` (..., 3, 3):
    eigenvalues (ascending) and eigenvectors (columns, camera 0's frame) of the information on ``dT`` with
    ``s`` free (Schur complement of the scale entry), and ``scale_unobservable`` (...) bool.
    """
    H, g, tt = normal_equations(translation_quadratic(Z), dR.unsqueeze(-3))
    _, H_pinv = pinv_solve(H, g)
    rss = (tt - 2 * (x * g).sum(-1) + (x.unsqueeze(-2) @ H @ x.unsqueeze(-1)).squeeze((-1, -2))).clamp_min(0)
    dof = 3 * rows - 4
    sigma2 = torch.where(dof > 0, rss / dof.clamp_min(1), torch.inf)  # exactly determined: no residual to tell
    h_ss = H[..., 3, 3].clamp_min(1e-300)
    info = H[..., :3, :3] - H[..., :3, 3:] @ H[..., 3:, :3] / h_ss[..., None, None]
    information, directions = guarded_eigh(info)
    # Information on s with dT free (Schur complement of the dT block); none: the scale is unobservable.
    h_TT_pinv = pinv_solve(H[..., :3, :3], H[..., :3, 3])[0]
    scale_information = H[..., 3, 3] - (H[..., 3, :3] * h_TT_pinv).sum(-1)
    cov = torch.where(sigma2[..., None, None].isinf(), torch.inf, sigma2[..., None, None] * H_pinv)
    return {"covariance": cov, "information": information, "directions": directions,
            "scale_unobservable": scale_information <= UNOBSERVABLE_RELATIVE * h_ss}  # fmt: skip


def unobservable_directions(information: Tensor) -> Tensor:
    """Mask (..., 3) of the information eigen-directions that carry too little information (see above)."""
    relative = information < UNOBSERVABLE_RELATIVE * information[..., -1:]
    return relative | (information < UNOBSERVABLE_ABSOLUTE)


def rls_update(x: Tensor, C: Tensor, B: Tensor, b: Tensor, forgetting: float = 1.0) -> tuple[Tensor, Tensor]:
    """One block update of recursive least squares with forgetting factor ``lam``.

    Args:
        x: (..., n) estimate. C: (..., n, n) its (scaled) covariance, ``C0`` at the start.
        B: (..., m, n) new rows. b: (..., m) new targets.

    ``Gamma = (I + B C B^T / lam)^-1``, ``G = C B^T Gamma / lam``, ``x += G (b - B x)``,
    ``C = C / lam - G Gamma^-1 G^T``. Equals batch least squares with prior ``(x0, C0)``
    (ridge toward ``x0``) when ``lam = 1``.
    """
    eye = torch.eye(B.shape[-2], dtype=B.dtype, device=B.device)
    Gamma_inv = eye + B @ C @ B.mT / forgetting
    G = torch.linalg.solve(Gamma_inv, B @ C.mT).mT / forgetting  # C B^T Gamma, Gamma symmetric
    x = x + (G @ (b - (B @ x.unsqueeze(-1)).squeeze(-1)).unsqueeze(-1)).squeeze(-1)
    C = C / forgetting - G @ Gamma_inv @ G.mT
    return x, (C + C.mT) / 2
