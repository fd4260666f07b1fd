"""The 1-sigma uncertainty and observability of a rig reconstruction's extrinsics, from its reprojection Jacobian.

The bundle adjustment's Gauss-Newton information ``J^T J / sigma^2`` over every rig frame's pose, every 3-D point
and every extrinsic is reduced to the extrinsics by Schur complements (points first, then frames), so each
camera's 6x6 information holds what the whole reconstruction knows of it. The gauge is fixed as COLMAP's BA fixes
it: the first registered frame's pose, and the scale through one coordinate of the frame farthest from it; where
camera 0's positions are priors (a metric trajectory of a stated noise), they fix it instead, with the uncertainty
they leave in the scale.
Directions of the translation that the data do not pin are reported unobservable instead of given a number: those
whose information vanishes against the best-known one, and those whose 1-sigma exceeds a tenth of the lever arm's
length (a car's camera height on planar motion: shifting camera k and its points along the common rotation axis
changes no image, so only the trajectory's small departures from the plane inform it; measured on the rendered
cars: 1-sigma 0.22 m on a 1.35 m lever arm, 0.02-0.04 m in the plane).

Not pycolmap's ``estimate_ba_covariance``: in pycolmap 4.2 it stops on a rig's non-reference images (its check
``image.IsRefInFrame()``), and ``sensor_from_rig`` is no parameter block it can be asked about.

Convention: camera k's extrinsic ``E = T_cam0_camk = inverse(sensor_from_rig)``; its perturbation is
``E exp(dxi)`` mapped to camera 0's frame: rotation (rad) and translation (reconstruction units) in camera 0's axes.
Projection is PINHOLE in COLMAP's pixels; sigma^2 is the mean squared reprojection residual.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pycolmap
import scipy.sparse as sp

from ocalib.geometry.directions import touched_axes
from ocalib.geometry.se3 import cross_matrix
from ocalib.rigba.colmap import to_matrix

UNOBSERVABLE = 1e-6  # information below this share of the best-known translation direction's: unobservable
WEAK_SHARE = 0.1  # a translation direction whose 1-sigma exceeds this share of the lever arm's length: unobservable
DAMPING = (
    1e-12  # relative damping of each point's 3x3 information, against exact singularity (1e-9 moved the result 3 %)
)


@dataclass
class ExtrinsicUncertainty:
    """Per camera k >= 1: ``covariance`` (6, 6) (rotation rad, translation; camera 0's axes) on the observable
    directions, ``unobservable`` (n, 3) unit translation directions the data do not fix (n = 0..3)."""

    covariance: np.ndarray
    unobservable: np.ndarray

    @property
    def rotation_std(self) -> np.ndarray:
        """(3,) rad about camera 0's axes; NaN where the variance came out negative (a covariance broken by rounding:
        not a measurement)."""
        variance = np.diag(self.covariance)[:3]
        return np.sqrt(np.where(variance >= 0, variance, np.nan))

    @property
    def translation_std(self) -> np.ndarray:
        """(3,) along camera 0's axes; inf along an axis an unobservable direction has a share of (over
        ``ocalib.geometry.directions.UNOBSERVABLE_AXIS_SHARE``)."""
        std = np.sqrt(np.clip(np.diag(self.covariance)[3:], 0, None))  # an unobservable axis: 0 up to rounding
        return np.where(touched_axes(self.unobservable), np.inf, std)


@dataclass
class Observations:
    """The reconstruction's observations as arrays: per observation its camera index (0 = reference), frame index,
    point index, pixel (2,); per frame its rig_from_world (F, 4, 4), or (F, C, 4, 4) where each camera captured its
    image of the frame at a pose of its own (cameras without a shared trigger; the frame's perturbation moves them
    all); per point xyz (P, 3); per camera its sensor_from_rig (C, 4, 4) and pinhole (fx, fy, cx, cy) (C, 4)."""

    camera: np.ndarray
    frame: np.ndarray
    point: np.ndarray
    xy: np.ndarray
    rig_from_world: np.ndarray
    xyz: np.ndarray
    sensor_from_rig: np.ndarray
    pinhole: np.ndarray


def extrinsic_uncertainty(rec: pycolmap.Reconstruction, camera_ids: list[int]) -> list[ExtrinsicUncertainty]:
    """The uncertainty of cameras ``camera_ids[1:]`` (COLMAP camera ids, the reference first) in ``rec``."""
    return observations_uncertainty(_observations(rec, camera_ids))


def observations_uncertainty(
    obs: Observations,
    weak_share: float = WEAK_SHARE,
    fitted: np.ndarray | None = None,
    poses_held: bool = False,
    position_noise: float | None = None,
) -> list[ExtrinsicUncertainty]:
    """The uncertainty of cameras 1..C-1 of the bundle-adjustment problem ``obs``; ``weak_share``: see
    :data:`WEAK_SHARE` (0: a translation direction is unobservable only where its information vanishes);
    ``fitted`` (N,) bool: the observations whose residuals give sigma^2 (None: all; those of a camera held where it
    may not be are misfit, not noise). The frames' poses: ``poses_held``, given (no frame columns, no gauge: the
    poses fix it); else with ``position_noise`` (> 0, the reconstruction's units per axis) solved with each frame's
    camera-0 position a prior of that noise (the priors fix the gauge: what they leave free, a rotation about the
    line of collinear positions, moves no extrinsic); else solved with the gauge fixed as COLMAP's BA fixes it."""
    C, F = len(obs.sensor_from_rig), len(obs.rig_from_world)
    priors = not poses_held and bool(position_noise)
    Je, Jf, Jp, r = _jacobians(obs)
    N = len(obs.camera)
    rows = np.arange(2 * N).reshape(N, 2)
    # Columns: extrinsics of cameras 1..C-1 (6 each), then, unless the poses are held, frames (6 each) less the
    # gauge's 7.
    cols_e = 6 * (obs.camera - 1)[:, None] + np.arange(6)
    cols_f = 6 * (C - 1) + 6 * obs.frame[:, None] + np.arange(6)
    J_c = sp.csr_matrix(
        (
            np.concatenate([Je[obs.camera > 0].ravel(), Jf.ravel()]),
            (
                np.concatenate([np.repeat(rows[obs.camera > 0], 6, 1).ravel(), np.repeat(rows, 6, 1).ravel()]),
                np.concatenate([np.tile(cols_e[obs.camera > 0], (1, 2)).ravel(), np.tile(cols_f, (1, 2)).ravel()]),
            ),
        ),
        shape=(2 * N, 6 * (C - 1 + F)),
    )
    ne = 6 * (C - 1)
    if poses_held:
        keep = np.arange(ne)
    else:
        keep = np.setdiff1d(np.arange(6 * (C - 1 + F)), _gauge_columns(obs, C))
    J_c = J_c[:, keep]
    P = len(obs.xyz)
    J_p = sp.csr_matrix(
        (Jp.ravel(), (np.repeat(rows, 3, 1).ravel(), np.tile(3 * obs.point[:, None] + np.arange(3), (1, 2)).ravel())),
        shape=(2 * N, 3 * P),
    )
    H_pp = _block_diagonal(J_p, P)
    H_cp = (J_c.T @ J_p).tocsr()
    S = (J_c.T @ J_c).toarray() - (H_cp @ H_pp @ H_cp.T).toarray()
    if fitted is not None and fitted.any():  # the mean squared residual of the fitted, scaled as the whole's
        r = r.reshape(N, 2)[fitted].ravel() * np.sqrt(N / fitted.sum())
    sigma2 = float(r @ r) / max(1, 2 * N - S.shape[0] - 3 * P)
    if priors:
        info = _marginal_with_position_priors(S, obs, keep[ne:] - ne, sigma2 / position_noise**2)
    else:
        info = S[:ne, :ne] - S[:ne, ne:] @ np.linalg.solve(S[ne:, ne:], S[ne:, :ne])
    out = []
    for k in range(1, C):
        block = info[6 * (k - 1) : 6 * k, 6 * (k - 1) : 6 * k] / sigma2
        E = np.linalg.inv(obs.sensor_from_rig[k])
        out.append(_in_camera0(block, E[:3, :3], weak_share * float(np.linalg.norm(E[:3, 3]))))
    return out


def _in_camera0(info: np.ndarray, R: np.ndarray, weak: float) -> ExtrinsicUncertainty:
    """Information of sensor_from_rig's left perturbation -> covariance of ``E = inverse`` in camera 0's axes, with
    the translation directions the data do not pin marked unobservable (the covariance covers the others); ``weak``:
    the 1-sigma (in the translation's units) above which a direction counts as not pinned (0: none)."""
    A = np.zeros((6, 6))
    A[:3, :3] = A[3:, 3:] = -R  # E' = E exp(-dxi): rotation -R w, translation -R v (first order)
    info = A @ info @ A.T  # A is orthogonal up to sign: the information transforms as the covariance does
    I_rr, I_rt, I_tt = info[:3, :3], info[:3, 3:], info[3:, 3:]
    marginal_t = I_tt - I_rt.T @ np.linalg.solve(I_rr, I_rt)  # the translation's information, the rotation free
    lam, V = np.linalg.eigh((marginal_t + marginal_t.T) / 2)
    weak = (lam < UNOBSERVABLE * max(lam.max(), 1e-300)) | ((weak > 0) & (lam * weak**2 < 1))
    basis = np.zeros((6, 6))  # rotation axes, then the translation's eigen-directions
    basis[:3, :3], basis[3:, 3:] = np.eye(3), V
    sub = basis[:, np.concatenate([np.ones(3, bool), ~weak])]  # the inverse restricted to the observable directions
    cov = sub @ np.linalg.inv(sub.T @ info @ sub) @ sub.T
    return ExtrinsicUncertainty(cov, V[:, weak].T.copy())


def _marginal_with_position_priors(S: np.ndarray, obs: Observations, frame_columns: np.ndarray, weight: float):
    """The extrinsics' information from ``S`` (their ``ne`` columns, then the frames' kept ``frame_columns`` of 6
    per frame: the gauge fixed) with each frame's camera-0 position a prior of information ``weight`` per axis (in
    the units of ``S``). The priors act through a similarity of the gauge-fixed window onto their frame (rotation,
    translation, log scale: 7 columns the images know nothing of, so none of their information is left in a
    direction they do not fix); its scale also carries the extrinsics' translations into the priors' units, its
    rotation and translation move no extrinsic. To first order at the identity a position ``c = -R^T t`` moves by
    ``-R^T v`` under its frame's perturbation (w, v) and by ``-[c]x omega + tau + lambda c`` under the
    similarity's; an extrinsic's ``v`` by ``lambda t`` (``t`` its sensor_from_rig's translation)."""
    T = obs.rig_from_world if obs.rig_from_world.ndim == 3 else obs.rig_from_world[:, 0]  # camera 0's
    ne = len(S) - len(frame_columns)
    F = len(T)
    centres = -np.einsum("fji,fj->fi", T[:, :3, :3], T[:, :3, 3])
    J = np.zeros((3 * F, 6 * F + 7))
    for f in range(F):
        J[3 * f : 3 * f + 3, 6 * f + 3 : 6 * f + 6] = -T[f, :3, :3].T
        J[3 * f : 3 * f + 3, 6 * F :] = np.concatenate([-cross_matrix(centres[f]), np.eye(3), centres[f][:, None]], 1)
    J = J[:, np.concatenate([frame_columns, 6 * F + np.arange(7)])]
    full = np.zeros((len(S) + 7, len(S) + 7))  # extrinsics, frames, similarity (its log scale last)
    full[: len(S), : len(S)] = S
    full[ne:, ne:] += weight * J.T @ J
    turn = len(S) + np.arange(3)  # the similarity's rotation: about the line of collinear positions free, and inert
    full[turn, turn] += DAMPING * np.trace(full[np.ix_(turn, turn)])
    kept = np.append(np.arange(ne), len(full) - 1)
    rest = np.setdiff1d(np.arange(len(full)), kept)
    info = full[np.ix_(kept, kept)] - full[np.ix_(kept, rest)] @ np.linalg.solve(
        full[np.ix_(rest, rest)], full[np.ix_(rest, kept)]
    )
    M = np.eye(ne + 1)  # (extrinsics in the priors' units, log scale) -> (in the window's, log scale)
    M[:ne, ne] = -np.concatenate([np.append(np.zeros(3), sensor[:3, 3]) for sensor in obs.sensor_from_rig[1:]])
    info = M.T @ info @ M
    return info[:ne, :ne] - np.outer(info[:ne, ne], info[ne, :ne]) / info[ne, ne]


def _block_diagonal(J_p: sp.csr_matrix, P: int) -> sp.csr_matrix:
    """The inverse of each point's 3x3 information block (damped), as a sparse block-diagonal matrix."""
    H = (J_p.T @ J_p).tocsr()
    blocks = np.zeros((P, 3, 3))
    for i in range(3):
        for j in range(3):
            blocks[:, i, j] = np.asarray(H[i::3, j::3].diagonal()).ravel()
    scale = np.trace(blocks, axis1=1, axis2=2)[:, None, None] / 3
    inv = np.linalg.inv(blocks + DAMPING * scale * np.eye(3) + 1e-300 * np.eye(3))
    idx = 3 * np.arange(P)[:, None, None] + np.arange(3)
    return sp.csr_matrix(
        (
            inv.ravel(),
            (np.broadcast_to(idx.transpose(0, 2, 1), (P, 3, 3)).ravel(), np.broadcast_to(idx, (P, 3, 3)).ravel()),
        ),
        shape=(3 * P, 3 * P),
    )


def _gauge_columns(obs: Observations, C: int) -> np.ndarray:
    """The columns the gauge fixes: the first frame's 6, and the scale through the translation coordinate of the frame
    farthest from it that the scale moves most."""
    T = obs.rig_from_world if obs.rig_from_world.ndim == 3 else obs.rig_from_world[:, 0]
    centres = -np.einsum("fji,fj->fi", T[:, :3, :3], T[:, :3, 3])
    far = int(np.argmax(np.linalg.norm(centres - centres[0], axis=1)))
    direction = T[far, :3, :3] @ (centres[far] - centres[0])  # how the scale moves the far frame's translation
    base = 6 * (C - 1)
    return np.concatenate([base + np.arange(6), [base + 6 * far + 3 + int(np.argmax(np.abs(direction)))]])


def _jacobians(obs: Observations):
    """Per observation the reprojection Jacobians (N, 2, 6) extrinsic, (N, 2, 6) frame, (N, 2, 3) point and the
    residuals (2N,). Perturbations are on the left: ``T <- exp(dxi) T`` with ``dxi = (w, v)``."""
    T_f = obs.rig_from_world[obs.frame] if obs.rig_from_world.ndim == 3 else obs.rig_from_world[obs.frame, obs.camera]
    T_s = obs.sensor_from_rig[obs.camera]
    Y = np.einsum("nij,nj->ni", T_f[:, :3, :3], obs.xyz[obs.point]) + T_f[:, :3, 3]  # rig coordinates
    Pc = np.einsum("nij,nj->ni", T_s[:, :3, :3], Y) + T_s[:, :3, 3]  # camera coordinates
    fx, fy, cx, cy = obs.pinhole[obs.camera].T
    z = Pc[:, 2]
    proj = np.stack([fx * Pc[:, 0] / z + cx, fy * Pc[:, 1] / z + cy], 1)
    r = (proj - obs.xy).ravel()
    Jpi = np.zeros((len(z), 2, 3))
    Jpi[:, 0, 0], Jpi[:, 0, 2] = fx / z, -fx * Pc[:, 0] / z**2
    Jpi[:, 1, 1], Jpi[:, 1, 2] = fy / z, -fy * Pc[:, 1] / z**2
    Je = np.concatenate([Jpi @ -cross_matrix(Pc), Jpi], 2)
    JR = Jpi @ T_s[:, :3, :3]
    Jf = np.concatenate([JR @ -cross_matrix(Y), JR], 2)
    Jp = JR @ T_f[:, :3, :3]
    return Je, Jf, Jp, r


def _observations(rec: pycolmap.Reconstruction, camera_ids: list[int]) -> Observations:
    camera_index = {cid: i for i, cid in enumerate(camera_ids)}
    frame_ids = sorted(rec.reg_frame_ids())
    frame_index = {fid: i for i, fid in enumerate(frame_ids)}
    point_ids = sorted(rec.point3D_ids())
    point_index = {pid: i for i, pid in enumerate(point_ids)}
    camera, frame, point, xy = [], [], [], []
    for image in rec.images.values():
        if not image.has_pose or image.camera_id not in camera_index:
            continue
        for p in image.get_observation_points2D():
            camera.append(camera_index[image.camera_id])
            frame.append(frame_index[image.frame_id])
            point.append(point_index[p.point3D_id])
            xy.append(p.xy)
    rig = next(iter(rec.rigs.values()))
    sensors = [np.eye(4)] + [
        to_matrix(rig.sensor_from_rig(pycolmap.sensor_t(pycolmap.SensorType.CAMERA, cid))) for cid in camera_ids[1:]
    ]
    return Observations(
        camera=np.asarray(camera),
        frame=np.asarray(frame),
        point=np.asarray(point),
        xy=np.asarray(xy, dtype=np.float64),
        rig_from_world=np.stack([to_matrix(rec.frame(fid).rig_from_world) for fid in frame_ids]),
        xyz=np.stack([rec.point3D(pid).xyz for pid in point_ids]),
        sensor_from_rig=np.stack(sensors),
        pinhole=np.stack([rec.camera(cid).params for cid in camera_ids]),
    )
