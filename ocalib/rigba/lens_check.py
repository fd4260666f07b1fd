"""Whether each camera's lens is modelled: a bundle adjustment's residuals regressed on radial distortion.

A lens left out of ``rig.yaml`` (or a wrong one) leaves residuals that point away from, or towards, the principal
point and grow with the radius; the adjustment absorbs part of the distortion into the poses and points, never all
of it. Per camera the residuals ``e`` (observed minus projected pixels) are fitted with
``e = (k1 r^2 + k2 r^4) (fx x, fy y)``, ``(x, y)`` the point's normalised projection (``r^2 = x^2 + y^2``): the fit's
displacement at the farthest image corner says how much lens is missing, its F statistic against no distortion
whether it is there at all.

Convention: pixels and principal point in COLMAP's convention (pixel centres at +0.5), as the reconstruction keeps
them; a camera with a lens is read through :func:`ocalib.rigba.colmap.pinhole_equivalent` first.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pycolmap
from scipy.stats import f as f_distribution

MAX_CORNER_PX = 0.5  # a radial residual this large at the image corner is a lens missing from the model
FALSE_ALARM = 1e-6  # of the F test against no radial residual


@dataclass(frozen=True)
class RadialResidual:
    """One camera's radial residual: ``corner_px`` its size at the farthest image corner (pixels, signed: > 0
    outwards), ``f_statistic`` against none (F with 2 and ``observations`` * 2 - 2 degrees of freedom)."""

    corner_px: float
    f_statistic: float
    observations: int

    @property
    def significant(self) -> bool:
        """A lens is missing or wrong: the residual is both larger than :data:`MAX_CORNER_PX` and real."""
        threshold = f_distribution.ppf(1 - FALSE_ALARM, 2, max(2 * self.observations - 2, 1))
        return bool(abs(self.corner_px) > MAX_CORNER_PX and self.f_statistic > threshold)


def radial_residual(
    residuals: np.ndarray, normalised: np.ndarray, focal: np.ndarray, corner: np.ndarray
) -> RadialResidual:
    """The radial residual of observations ``residuals`` (n, 2) pixels at normalised projections ``normalised``
    (n, 2), with focal lengths ``focal`` (2,) and the farthest image corner ``corner`` (2,) in normalised
    coordinates -> :class:`RadialResidual`."""
    n = len(residuals)
    if n < 10:
        return RadialResidual(0.0, 0.0, n)
    r2 = (normalised**2).sum(1, keepdims=True)
    radial = normalised * focal
    A = np.stack([(r2 * radial).ravel(), (r2**2 * radial).ravel()], 1)
    e = residuals.ravel()
    k = np.linalg.lstsq(A, e, rcond=None)[0]
    before, after = float(e @ e), float(((e - A @ k) ** 2).sum())
    f_statistic = (before - after) / 2 / max(after / (len(e) - 2), 1e-300)
    rc2 = float(corner @ corner)
    corner_px = (k[0] * rc2 + k[1] * rc2**2) * float(np.linalg.norm(corner * focal))
    return RadialResidual(float(corner_px), float(f_statistic), n)


def radial_residuals(rec: pycolmap.Reconstruction) -> dict[int, RadialResidual]:
    """Per camera id of ``rec`` (PINHOLE cameras: see :func:`ocalib.rigba.colmap.pinhole_equivalent`), the radial
    residual of its registered images' observations."""
    gathered: dict[int, tuple[list, list]] = {cid: ([], []) for cid in rec.cameras}
    for image in rec.images.values():
        if not image.has_pose:
            continue
        seen = [p for p in image.points2D if p.has_point3D()]
        if not seen:
            continue
        T = image.cam_from_world().matrix()
        X = np.array([rec.points3D[p.point3D_id].xyz for p in seen]) @ T[:, :3].T + T[:, 3]
        gathered[image.camera_id][0].append(np.array([p.xy for p in seen]))
        gathered[image.camera_id][1].append(X[:, :2] / X[:, 2:])
    out = {}
    for cid, (observed, normalised) in gathered.items():
        camera = rec.cameras[cid]
        focal, centre = np.asarray(camera.params[:2]), np.asarray(camera.params[2:4])
        corners = (
            np.array([[0, 0], [camera.width, 0], [0, camera.height], [camera.width, camera.height]]) - centre
        ) / focal
        corner = corners[np.argmax((corners**2).sum(1))]
        if not observed:
            out[cid] = RadialResidual(0.0, 0.0, 0)
            continue
        xy = np.concatenate(normalised)
        out[cid] = radial_residual(np.concatenate(observed) - (xy * focal + centre), xy, focal, corner)
    return out
