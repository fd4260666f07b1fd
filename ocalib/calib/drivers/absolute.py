"""Rig calibration from absolute poses (``AX = YB``), on-line with O(1) statistics.

The motion pairs of :class:`~ocalib.calib.drivers.online.OnlineCalibrator` suit drifting trajectories (VO, SLAM). Where
each pose carries its own independent error instead (a calibration target seen by each camera, motion capture,
a robot arm: OpenCV's hand-eye protocol), a pose takes part in several pairs, their residuals are correlated,
and the pairs waste information. Here each frame gives one equation in the unknown rig ``X`` and the unknown
pose ``Y`` of camera k's world in camera 0's world,

    ``C0_i Y = X Ck_i``:   ``R Rk_i = R0_i Ry``   and   ``s R tk_i + t = R0_i ty + t0_i``,

where ``C = P^-1 = (R., t.)`` is a camera's world-to-camera pose (camera k's translation in its own units).
Both residuals live in camera 0's frame; the translation one carries each pose's translation error as it is
measured (a target's position in the camera). Every frame adds to two sums, O(1) in the number of frames:

    ``K = sum_i kron(R0_i, Rk_i)`` (9 x 9):  rotation cost ``E_r = 3 n - vec(R) . K vec(Ry)`` (half the squared
    Frobenius residual, about the angle squared);
    ``M = sum_i D_i^T D_i`` (16 x 16):  translation cost ``E_t = z^T M z``, ``z = (vec(s R), t, ty, 1)``.

The closed form takes ``vec(R)`` and ``vec(Ry)`` from the top singular pair of ``K`` (noise-free,
``K vec(Ry) = n vec(R)``), then ``(s, t, ty)`` by linear least squares. Newton steps then minimise
``E_r / sr^2 + E_t / st^2`` over all 13 unknowns, with ``sr^2``, ``st^2`` the closed form's residual variances:
the result equals a batch nonlinear least-squares solve of all frames' residuals, every frame.

That residual suits poses whose translation error is in the camera frame (PnP on a target). For poses whose
error is in the camera's position (motion capture), :class:`AbsoluteCalibrator` with ``pose_error="world"``
solves the same equations with camera and world exchanged (``P0_i X = Y Pk_i``, residual in camera 0's world).

Convention: poses in are camera-to-world (..., C, 4, 4), camera 0 the reference; ``(R, t)`` is ``T_cam0_camk``
(``p_cam0 = R p_camk + t``), ``s`` multiplies camera-k units into camera-0 units, ``(Ry, ty)`` is
``T_world0_worldk``; matrices are vectorised row by row.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import torch
from kornia.geometry.conversions import axis_angle_to_rotation_matrix
from torch import Tensor, nn

from ocalib.calib.drivers.options import POSE_ERRORS  # where the poses' translation error lives
from ocalib.calib.stages.gating import check_poses, rig_poses
from ocalib.calib.stages.planar import skew
from ocalib.geometry.constants import constant_cache
from ocalib.geometry.pose import invert_pose
from ocalib.geometry.quaternion import rotation_matrix_to_quaternion
from ocalib.io.jsonable import finite_or_null

UNKNOWNS = 13  # rotation (3, about camera k's axes), world rotation (3), scale, translation (3), world translation (3)
ROTATION_GAP_MIN = 1e-3  # rotation observable: top two singular values of K at least this far apart, per frame
SWAP = [3, 4, 5, 0, 1, 2, 6, 10, 11, 12, 7, 8, 9]  # the order of UNKNOWNS with X and Y exchanged
NEWTON_STEPS = 10
CONVERGED = 1e-9  # Newton steps (radians, units) this small are taken without comparing costs


def absolute_rows(R0: Tensor, Rk: Tensor, t0: Tensor, tk: Tensor) -> tuple[Tensor, Tensor]:
    """One frame's statistics. R0, Rk: (..., 3, 3), t0, tk: (..., 3), world-to-camera poses of camera 0 and k.

    Returns ``kron(R0, Rk)`` (..., 9, 9) and the translation design ``D`` (..., 3, 16) with ``D z`` the
    translation residual ``s R tk + t - R0 ty - t0``.
    """
    kron = (R0[..., :, None, :, None] * Rk[..., None, :, None, :]).flatten(-4, -3).flatten(-2, -1)
    eye = torch.eye(3, dtype=R0.dtype, device=R0.device).expand_as(R0)
    D = torch.cat([(eye[..., :, :, None] * tk[..., None, None, :]).flatten(-2), eye, -R0, -t0.unsqueeze(-1)], -1)
    return kron, D


def _project(A: Tensor) -> Tensor:
    """The rotation nearest to A (..., 3, 3) (polar factor with det +1)."""
    U, _, Vh = torch.linalg.svd(A)
    d = torch.linalg.det(U @ Vh)
    return U @ torch.diag_embed(torch.stack([torch.ones_like(d), torch.ones_like(d), d], -1)) @ Vh


def _translation_closed_form(M: Tensor, R: Tensor) -> Tensor:
    """(s, t, ty) (..., 7) minimising ``z^T M z`` with ``vec(s R)`` fixed up to s."""
    H = torch.zeros(*R.shape[:-2], 16, 7, dtype=R.dtype, device=R.device)
    H[..., :9, 0] = R.flatten(-2)
    H[..., 9:15, 1:] = torch.eye(6, dtype=R.dtype, device=R.device)
    A = H.mT @ M @ H
    b = H.mT @ M[..., :, 15:]
    return torch.linalg.solve_ex(A, -b)[0].squeeze(-1)


def _costs(K: Tensor, M: Tensor, n: Tensor, R: Tensor, Ry: Tensor, x: Tensor) -> tuple[Tensor, Tensor]:
    """Rotation and translation costs (...,) at ``R, Ry`` (..., 3, 3) and ``x = (s, t, ty)`` (..., 7)."""
    Er = 3 * n - (R.flatten(-2).unsqueeze(-2) @ K @ Ry.flatten(-2).unsqueeze(-1))[..., 0, 0]
    one = torch.ones_like(x[..., :1])
    z = torch.cat([x[..., :1] * R.flatten(-2), x[..., 1:], one], -1)
    return Er, (z.unsqueeze(-2) @ M @ z.unsqueeze(-1))[..., 0, 0]


@constant_cache
def _generators(dtype: torch.dtype, device: torch.device) -> tuple[Tensor, Tensor]:
    """so(3) generators ``G_i = [e_i]x`` (3, 3, 3) and their symmetrised products ``(G_i G_j + G_j G_i) / 2``
    (3, 3, 3, 3): ``R exp(a) = R (I + sum a_i G_i + sum a_i a_j S_ij / 2 + ...)``."""
    G = skew(torch.eye(3, dtype=dtype, device=device))
    GG = G[:, None] @ G[None, :]
    return G, (GG + GG.transpose(0, 1)) / 2


def local_derivatives(K, M, R, Ry, x, wr, wt) -> tuple[Tensor, Tensor]:
    """Gradient (..., 13) and Hessian (..., 13, 13) of ``wr E_r + wt E_t`` at ``R exp(a), Ry exp(b), x + dx``,
    ``p = (a, b, dx) = 0`` (the order of :data:`UNKNOWNS`). K (..., 9, 9), M (..., 16, 16), R, Ry (..., 3, 3),
    x (..., 7), wr, wt (...)."""
    G, S = _generators(R.dtype, R.device)
    vec = lambda A: A.flatten(-2)  # noqa: E731
    Jr = vec(R[..., None, :, :] @ G).mT  # (..., 9, 3): d vec(R exp(a)) / da
    Jy = vec(Ry[..., None, :, :] @ G).mT
    Sr = vec(R[..., None, None, :, :] @ S)  # (..., 3, 3, 9): second derivatives
    Sy = vec(Ry[..., None, None, :, :] @ S)
    r, ry, s = vec(R), vec(Ry), x[..., :1]
    z = torch.cat([s * r, x[..., 1:], torch.ones_like(s)], -1)
    Mz = (M @ z.unsqueeze(-1)).squeeze(-1)
    Kry = (K @ ry.unsqueeze(-1)).squeeze(-1)
    Ktr = (r.unsqueeze(-2) @ K).squeeze(-2)
    Jz = torch.zeros(*R.shape[:-2], 16, UNKNOWNS, dtype=R.dtype, device=R.device)  # dz / dp
    Jz[..., :9, :3] = s.unsqueeze(-1) * Jr
    Jz[..., :9, 6] = r
    Jz[..., 9:15, 7:] = torch.eye(6, dtype=R.dtype, device=R.device)
    wr_, wt_ = wr[..., None], wt[..., None]
    grad = 2 * wt_ * (Jz.mT @ Mz.unsqueeze(-1)).squeeze(-1)
    grad[..., :3] -= wr_ * (Kry.unsqueeze(-2) @ Jr).squeeze(-2)
    grad[..., 3:6] -= wr_ * (Ktr.unsqueeze(-2) @ Jy).squeeze(-2)
    hess = 2 * wt_[..., None] * (Jz.mT @ M @ Jz)
    Mz_r = Mz[..., :9]
    hess[..., :3, :3] += (Sr * (2 * wt_ * s * Mz_r - wr_ * Kry)[..., None, None, :]).sum(-1)
    hess[..., 3:6, 3:6] -= wr_[..., None] * (Sy * Ktr[..., None, None, :]).sum(-1)
    ab = -wr_[..., None] * (Jr.mT @ K @ Jy)
    hess[..., :3, 3:6] += ab
    hess[..., 3:6, :3] += ab.mT
    a_s = 2 * wt_ * (Mz_r.unsqueeze(-2) @ Jr).squeeze(-2)
    hess[..., :3, 6] += a_s
    hess[..., 6, :3] += a_s
    return grad, hess


def _apply(R, Ry, x, step):
    return (
        R @ axis_angle_to_rotation_matrix(step[:, :3]),
        Ry @ axis_angle_to_rotation_matrix(step[:, 3:6]),
        x + step[:, 6:],
    )


def solve_absolute(
    K: Tensor, M: Tensor, n: Tensor, sigma: Tensor | None = None, steps: int = NEWTON_STEPS
) -> dict[str, Tensor]:
    """Calibrate from the sums of :func:`absolute_rows`: ``K`` (..., 9, 9), ``M`` (..., 16, 16) and ``n`` (...)
    weighted frames. ``sigma`` (..., 2): the noise ``(sr, st)`` that weighs the two costs (radians, camera-0
    units); default: the closed form's residuals.

    Returns a dict: ``sigma`` (the weights used); ``rotation`` (..., 3, 3), ``scale`` (...), ``translation``
    (..., 3), ``world_rotation``, ``world_translation``, all NaN where the rotation is unobservable (pure
    translation, rotation about one axis); ``singular_values`` (..., 9) of K; ``rotation_observable`` (its top
    two singular values at least ``ROTATION_GAP_MIN n`` apart); ``refined`` (where Newton ran: observable and
    at least 3 frames); ``covariance`` (..., 13, 13) of the unknowns in the order of :data:`UNKNOWNS` (inf where
    not refined); ``rotation_cost`` and ``translation_cost`` (``E_r``, ``E_t``).

    The closed form and the Newton iterations run detached; a last Newton step at the solution carries the
    gradient to the statistics (at a minimum, that step's derivative is the implicit function's), with the
    weights ``sigma`` held fixed.
    """
    shape = n.shape
    K, M, n = K.reshape(-1, 9, 9), M.reshape(-1, 16, 16), n.reshape(-1)
    with torch.no_grad():
        U, S, _ = torch.linalg.svd(K.detach())
        u = U[..., 0].unflatten(-1, (3, 3))
        u = u * torch.where(torch.linalg.det(u) < 0, -1.0, 1.0)[..., None, None].to(u)
        R = _project(u)
        Ry = _project((R.flatten(-2).unsqueeze(-2) @ K).squeeze(-2).unflatten(-1, (3, 3)))
        x = _translation_closed_form(M.detach(), R)
        Er, Et = _costs(K, M, n, R, Ry, x)
        observable = (S[:, 0] - S[:, 1]) > ROTATION_GAP_MIN * n.clamp_min(1)
        active = observable & (n >= 3)
        if sigma is None:
            tiny = torch.finfo(K.dtype).tiny / torch.finfo(K.dtype).eps
            sigma = torch.stack(
                [Er.clamp_min(0) / (3 * n - 6).clamp_min(1), Et.clamp_min(0) / (3 * n - 7).clamp_min(1)], -1
            )
            sigma = sigma.clamp_min(tiny).sqrt()
        sigma = sigma.detach().reshape(-1, 2).to(K)
        wr, wt = sigma[:, 0] ** -2, sigma[:, 1] ** -2
        scale = 1 / (wr + wt)  # the step does not depend on it; keeps the numbers near 1
        wr, wt = wr * scale, wt * scale
        cost = wr * Er + wt * Et
        for _ in range(steps):
            g, H = local_derivatives(K, M, R, Ry, x, wr, wt)
            step = -torch.linalg.solve_ex(H, g.unsqueeze(-1))[0].squeeze(-1)
            step = torch.where(active[:, None] & step.isfinite().all(-1, keepdim=True), step, 0)
            R1, Ry1, x1 = _apply(R, Ry, x, step)
            Er1, Et1 = _costs(K, M, n, R1, Ry1, x1)
            cost1 = wr * Er1 + wt * Et1
            small = step.abs().amax(-1) < CONVERGED  # below the cost's rounding: keep without comparing
            take = (cost1 <= cost) | small
            R, Ry = torch.where(take[:, None, None], R1, R), torch.where(take[:, None, None], Ry1, Ry)
            x, cost = torch.where(take[:, None], x1, x), torch.where(take, cost1, cost)
            if bool((small | ~take).all()):
                break
    g, H = local_derivatives(K, M, R, Ry, x, wr, wt)
    eye = torch.eye(UNKNOWNS, dtype=K.dtype, device=K.device)
    H = torch.where(active[:, None, None], H, eye)  # elsewhere no step, and no 0 * inf in its gradient
    if torch.is_grad_enabled() and (K.requires_grad or M.requires_grad):
        step = torch.where(active[:, None], -torch.linalg.solve(H, g.unsqueeze(-1)).squeeze(-1), 0)
        R, Ry, x = _apply(R, Ry, x, step)
    Er, Et = _costs(K, M, n, R, Ry, x)
    nan = torch.tensor(math.nan, dtype=K.dtype, device=K.device)  # no answer where the rotation is unobservable
    R, Ry, x = (torch.where(observable.view(-1, *[1] * (v.dim() - 1)), v, nan) for v in (R, Ry, x))
    # chi-square form: sum r^2 / sigma^2 = (wr Er + wt Et) / scale, whose Hessian is H / scale: cov = 2 (H / scale)^-1
    cov = 2 * torch.linalg.inv_ex(H.detach() / scale[:, None, None])[0]
    cov = torch.where(active[:, None, None] & cov.isfinite(), cov, math.inf)
    out = {
        "sigma": sigma,
        "rotation": R,
        "scale": x[:, 0],
        "translation": x[:, 1:4],
        "world_rotation": Ry,
        "world_translation": x[:, 4:],
        "singular_values": S,
        "rotation_observable": observable,
        "refined": active,
        "covariance": cov,
        "rotation_cost": Er,
        "translation_cost": Et,
    }
    return {k: v.reshape(*shape, *v.shape[1:]) for k, v in out.items()}


@dataclass
class AbsoluteCalibration:
    """Extrinsics of cameras 1..K against camera 0 for B rigs from absolute poses. Shapes lead with (B, K).

    It answers the attributes of :class:`~ocalib.calib.drivers.result.Calibration` that the command line reads (the
    result JSON, the trace, the warnings). Absolute poses have no planar route: rotation about one axis leaves
    the rotation unobservable and every estimate NaN.

    Convention: ``T_cam0_camk`` (``p_cam0 = R p_camk + t``), ``scale`` multiplies camera-k units into camera-0
    units, ``world_*`` is ``T_world0_worldk``; quaternions (w, x, y, z), w >= 0; rotation std in radians about
    camera k's axes, translation std along camera 0's.
    """

    rotation: Tensor  # (B, K, 3, 3)
    translation: Tensor  # (B, K, 3)
    scale: Tensor  # (B, K)
    world_rotation: Tensor  # (B, K, 3, 3)
    world_translation: Tensor  # (B, K, 3)
    rotation_singular_values: Tensor  # (B, K, 9) of the rotation sum K, descending
    rotation_observable: Tensor  # (B, K) bool
    covariance: Tensor  # (B, K, 13, 13) in the order of UNKNOWNS, inf where not refined
    rotation_cost: Tensor  # (B, K)
    translation_cost: Tensor  # (B, K)
    camera0_spread: Tensor  # (B, K) RMS spread of camera 0's world-to-camera translations (pose_error world: positions)
    frames: Tensor  # (B, K) weighted frames in the sums
    frames_used: Tensor  # (B, K) long
    frames_rejected: Tensor  # (B, K) long

    @cached_property
    def quaternion(self) -> Tensor:
        return rotation_matrix_to_quaternion(self.rotation)

    @property
    def planar_motion(self) -> Tensor:
        """(B, K) all False: there is no planar route (see the class docstring)."""
        return torch.zeros_like(self.rotation_observable)

    @cached_property
    def _std(self) -> Tensor:
        return torch.diagonal(self.covariance, dim1=-2, dim2=-1).clamp_min(0).sqrt()

    @property
    def rotation_std(self) -> Tensor:
        """(B, K, 3) 1-sigma in radians about camera k's axes."""
        return self._std[..., :3]

    @property
    def scale_std(self) -> Tensor:
        return self._std[..., 6]

    @property
    def translation_std(self) -> Tensor:
        """(B, K, 3) 1-sigma along camera 0's axes."""
        return self._std[..., 7:10]

    @cached_property
    def _translation_eigen(self) -> tuple[Tensor, Tensor, Tensor]:
        cov = self.covariance[..., 7:10, 7:10]
        finite = cov.isfinite().all(-1).all(-1)
        variance, directions = torch.linalg.eigh(torch.where(finite[..., None, None], cov, torch.eye(3).to(cov)))
        return variance.flip(-1), directions.flip(-1), finite

    @property
    def translation_directions(self) -> Tensor:
        """(B, K, 3, 3) principal directions (columns, camera 0's frame) of the translation error, weakest first."""
        return self._translation_eigen[1]

    @property
    def translation_unobservable(self) -> Tensor:
        """(B, K, 3) bool: every direction where there is no covariance (rotation unobservable, or < 3 frames)."""
        return ~self._translation_eigen[2].unsqueeze(-1).expand(*self.rotation_observable.shape, 3)

    @cached_property
    def residuals(self) -> dict[str, Tensor]:
        """RMS residuals per frame, (B, K): ``rotation_deg``, the angle between ``R Rk`` and ``R0 Ry``, and
        ``translation_relative``, the translation residual over ``camera0_spread`` (0: explained; about 1: no
        better than no translation)."""
        n = self.frames.clamp_min(1e-300)
        return {
            "rotation_deg": torch.rad2deg((self.rotation_cost.clamp_min(0) / n).sqrt()),
            "translation_relative": (self.translation_cost.clamp_min(0) / n).sqrt() / self.camera0_spread,
        }

    def camera_json(self, b: int, k: int) -> dict:
        """The JSON object of camera k+1 of rig b, in the schema of :class:`~ocalib.calib.drivers.result.Calibration`'s,
        with the world pose ``T_world0_worldk`` added."""
        get = lambda name: getattr(self, name)[b, k].detach().cpu().double()  # noqa: E731
        unobservable, directions = get("translation_unobservable").bool(), get("translation_directions")
        return finite_or_null(
            {
                "rotation": get("rotation").tolist(),
                "quaternion_wxyz": get("quaternion").tolist(),
                "translation": get("translation").tolist(),
                "scale": float(get("scale")),
                "world_rotation": get("world_rotation").tolist(),
                "world_translation": get("world_translation").tolist(),
                "frames_used": int(get("frames_used")),
                "frames_rejected": int(get("frames_rejected")),
                "rotation_std_deg": torch.rad2deg(get("rotation_std")).tolist(),
                "translation_std": get("translation_std").tolist(),
                "scale_std": float(get("scale_std")),
                "residuals": {name: float(v[b, k]) for name, v in self.residuals.items()},
                "observability": {
                    "rotation_singular_values": get("rotation_singular_values").tolist(),
                    "rotation_observable": bool(get("rotation_observable")),
                    "planar_motion": False,
                    "unobservable_translation_directions": [
                        directions[:, j].tolist() for j in range(3) if unobservable[j]
                    ],
                    "weakest_translation_direction": directions[:, 0].tolist(),
                },
            }
        )


class AbsoluteCalibrator(nn.Module):
    """On-line ``AX = YB`` calibration of B rigs of C cameras from absolute poses (see the module docstring).

    Every frame adds one row per camera k to the sums ``K`` and ``M`` (buffers: ``state_dict`` saves and restores
    a stream) and re-solves them; gradients flow to the poses.

    Args:
        num_cameras: C, camera 0 the reference. batch_size: B.
        pose_error: where the poses' translation error lives, which decides the frame of the translation residual:
            ``camera`` (the world-to-camera translation, as PnP on a calibration target gives it: the module
            docstring's equations) or ``world`` (the camera's position, as motion capture gives it). ``world``
            solves the same equations with the roles of camera and world exchanged: the poses go in as they are
            (camera-to-world read as world-to-camera), so that the residual lies in camera 0's world, and ``X``
            and ``Y`` swap places in the result. The wrong choice costs about 2x in translation error (tested).
        forgetting: ``lam`` in (0, 1]; old frames weigh ``lam`` per frame.
        pose_tolerance: poses with a non-finite entry or a rotation further than this from orthonormal are
            skipped and counted in ``frames_rejected``.
    """

    def __init__(self, num_cameras: int = 2, batch_size: int = 1, pose_error: str = "camera", forgetting: float = 1.0,
                 pose_tolerance: float = 1e-3, dtype: torch.dtype = torch.float64, device: torch.device | str | None = None):  # fmt: skip
        super().__init__()
        if num_cameras < 2:
            raise ValueError(f"a rig needs at least 2 cameras, got num_cameras={num_cameras}")
        if pose_error not in POSE_ERRORS:
            raise ValueError(f"pose_error must be one of {POSE_ERRORS}, got {pose_error!r}")
        self.pose_error = pose_error
        if not 0 < forgetting <= 1:
            raise ValueError(f"forgetting must be in (0, 1], got {forgetting}")
        self.num_cameras, self.batch_size, self.forgetting, self.pose_tolerance = (
            num_cameras,
            batch_size,
            forgetting,
            pose_tolerance,
        )
        B, K = batch_size, num_cameras - 1
        f = dict(dtype=dtype, device=device)
        self.register_buffer("K", torch.zeros(B, K, 9, 9, **f))
        self.register_buffer("M", torch.zeros(B, K, 16, 16, **f))
        self.register_buffer("frames", torch.zeros(B, K, **f))
        self.register_buffer("frames_used", torch.zeros(B, K, dtype=torch.long, device=device))
        self.register_buffer("frames_rejected", torch.zeros(B, K, dtype=torch.long, device=device))

    def reset(self) -> None:
        for buffer in self.buffers():
            buffer.zero_()

    def forward(self, poses: Tensor) -> AbsoluteCalibration:
        """Consume one synchronised frame. poses: (B, C, 4, 4) or (C, 4, 4) camera-to-world."""
        poses = rig_poses(poses, self.batch_size, self.num_cameras)
        C, valid = check_poses(poses.to(self.K.dtype), self.pose_tolerance)
        C = invert_pose(C) if self.pose_error == "camera" else C  # world-to-camera (world: roles exchanged)
        kron, D = absolute_rows(C[:, :1, :3, :3].expand_as(C[:, 1:, :3, :3]), C[:, 1:, :3, :3],
                                C[:, :1, :3, 3].expand_as(C[:, 1:, :3, 3]), C[:, 1:, :3, 3])  # fmt: skip
        used = valid[:, :1] & valid[:, 1:]  # (B, K)
        w = used.to(C.dtype)
        lam = self.forgetting
        self.K = lam * self.K + w[..., None, None] * kron
        self.M = lam * self.M + w[..., None, None] * D.mT @ D
        self.frames = lam * self.frames + w
        self.frames_used = self.frames_used + used
        self.frames_rejected = self.frames_rejected + ~used
        est = solve_absolute(self.K, self.M, self.frames)
        rig, world = ("rotation", "translation"), ("world_rotation", "world_translation")
        cov = est["covariance"]
        if self.pose_error == "world":  # X and Y exchanged (see the class docstring)
            rig, world = world, rig
            cov = cov[..., SWAP, :][..., :, SWAP]
        n = self.frames.clamp_min(1e-300)
        return AbsoluteCalibration(
            rotation=est[rig[0]], translation=est[rig[1]], scale=est["scale"],
            world_rotation=est[world[0]], world_translation=est[world[1]],
            rotation_singular_values=est["singular_values"], rotation_observable=est["rotation_observable"],
            covariance=cov, rotation_cost=est["rotation_cost"], translation_cost=est["translation_cost"],
            camera0_spread=((self.M[..., 15, 15] - self.M[..., 9:12, 15].square().sum(-1) / n) / n).clamp_min(0).sqrt(),
            frames=self.frames, frames_used=self.frames_used, frames_rejected=self.frames_rejected,
        )  # fmt: skip
