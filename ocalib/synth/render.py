"""Render one camera view of a :class:`~ocalib.synth.world.World`: colour and z-depth.

Anti-aliasing is ``s x s`` supersampling. Pixel-centre rays are traced against all boxes (tiled,
see :mod:`ocalib.synth.raycast`); a pixel whose 3x3 neighbourhood of centre rays hits one face of one
box has all its sub-samples on that face's plane (the face is convex), so they are intersected with
the plane directly; other pixels (edges, about 5-15%) trace each sub-sample against the boxes hit by
the four pixel centres around it. This equals full supersampling except for objects thinner than a
pixel. Interior pixels are shaded once with textures prefiltered to the pixel footprint
(:mod:`ocalib.synth.texture`), edge pixels ``s x s`` times with the sub-sample footprint.

Convention: ``pose`` is camera-to-world (``p_world = R p_cam + t``), float64; camera x right, y down,
z forward; ``K`` in pixels with integer pixel centres, through the camera's lens where it has one (OpenCV's models,
:mod:`ocalib.data.distortion`). Depth is the z-depth of the hit of the pixel
*centre* ray (0 for sky), so it is exact at pixel centres.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from ocalib.data.distortion import Distortion, undistort
from ocalib.errors import InputError
from ocalib.synth import raycast
from ocalib.synth.texture import GROUND, SKY, footprint, shade, sky
from ocalib.synth.world import World

NEAR, FAR = 0.05, 250.0


@dataclass
class WorldTensors:
    """A :class:`World` on a device: boxes (P, 6) float64, material (P,), albedo (P, 3), params (P, 4)."""

    boxes: Tensor
    material: Tensor
    albedo: Tensor
    params: Tensor

    @classmethod
    def from_world(cls, world: World, device="cpu") -> WorldTensors:
        def t(a, dtype):
            return torch.as_tensor(np.asarray(a), dtype=dtype, device=device)

        return cls(
            t(world.boxes, torch.float64),
            t(world.material, torch.long),
            t(world.albedo, torch.float32),
            t(world.params, torch.float32),
        )


def _pixel_dirs(K: Tensor, R: Tensor, u: Tensor, v: Tensor, distortion: Distortion | None = None) -> Tensor:
    """World directions (..., 3) float32 through pixel coordinates u, v (...) float64 (through the lens's inverse
    where there is one); camera z = 1."""
    cam = torch.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], torch.ones_like(u)], -1)
    if distortion is not None:
        cam[..., :2] = _through_lens(cam[..., :2], distortion)
    return (cam @ R.T).float()


def _through_lens(xy: Tensor, distortion: Distortion) -> Tensor:
    """Distorted normalised coordinates (..., 2) float64 -> the undistorted ones of the same rays."""
    out = undistort(xy.reshape(-1, 2).cpu().numpy(), distortion)
    if not np.isfinite(out).all():
        raise InputError(f"distortion {distortion.as_dict()}: no ray for some pixels (the lens folds back there)")
    return torch.from_numpy(out).to(xy.device).view_as(xy)


@lru_cache(maxsize=16)
def _lens_grid(K: tuple, height: int, width: int, distortion: Distortion) -> Tensor:
    """(H, W, 2) float64 undistorted normalised coordinates of the pixel centres of a camera (K as a 9-tuple)."""
    K = torch.tensor(K, dtype=torch.float64).view(3, 3)
    v, u = torch.meshgrid(
        torch.arange(height, dtype=torch.float64), torch.arange(width, dtype=torch.float64), indexing="ij"
    )
    x = torch.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]], -1)
    return _through_lens(x, distortion)


def _cull(rel: Tensor, Rt: Tensor, far: float) -> Tensor:
    """Indices of boxes (relative bounds (P, 6)) within ``far`` and not wholly behind the camera."""
    lo, hi = rel[:, :3], rel[:, 3:]
    dist = torch.maximum(torch.maximum(lo, -hi), torch.zeros_like(lo)).norm(dim=1)
    z_centre = ((lo + hi) / 2) @ Rt[2]
    radius = (hi - lo).norm(dim=1) / 2
    return ((dist < far) & (z_centre + radius > NEAR)).nonzero().squeeze(1)


def _faces(dirs: Tensor, hit: Tensor, rel32: Tensor, oz: float):
    """Axis (N,) and plane coordinate (N,) (relative to the camera) of the faces hit by rays (N, 3)."""
    b = hit.clamp_min(0)
    lo, hi = rel32[b, :3], rel32[b, 3:]
    axis = raycast.hit_axis(dirs, lo, hi)
    da = dirs.gather(1, axis[:, None]).squeeze(1)
    plane = torch.where(da > 0, lo.gather(1, axis[:, None]).squeeze(1), hi.gather(1, axis[:, None]).squeeze(1))
    axis = torch.where(hit == GROUND, 2, torch.where(hit == SKY, 0, axis))
    plane = torch.where(hit == GROUND, torch.full_like(plane, -oz), plane)
    return axis, plane


def render_view(
    world: WorldTensors, K, pose, height: int, width: int, supersample: int = 2, distortion: Distortion | None = None
):
    """Render a view -> (image (3, H, W) float32 in [0, 1], depth (H, W) float32 metres, 0 = sky).

    K (3, 3) and pose (4, 4) camera-to-world, float64 (numpy or torch); ``distortion``: the lens's (a ray per pixel
    through its inverse; the rays' pixel-centre grid cached per camera), None for a pinhole.
    """
    dev = world.boxes.device
    K = torch.as_tensor(np.asarray(K), dtype=torch.float64, device=dev)
    pose = torch.as_tensor(np.asarray(pose), dtype=torch.float64, device=dev)
    R, o = pose[:3, :3], pose[:3, 3]
    oz, s, S = float(o[2]), supersample, supersample**2
    v_pix, u_pix = torch.meshgrid(
        torch.arange(height, dtype=torch.float64, device=dev),
        torch.arange(width, dtype=torch.float64, device=dev),
        indexing="ij",
    )
    rel = world.boxes - o.repeat(2)
    near_boxes = _cull(rel, R.T, FAR)
    if distortion is None:
        dirs = _pixel_dirs(K, R, u_pix, v_pix)  # (H, W, 3)
        keep, rect = raycast.screen_rects(rel[near_boxes], R.T, K, height, width, NEAR, FAR)
    else:
        grid = _lens_grid(tuple(K.cpu().ravel().tolist()), height, width, distortion).to(dev)
        dirs = (torch.cat([grid, torch.ones_like(grid[..., :1])], -1) @ R.T).float()
        keep, rect = raycast.lens_rects(rel[near_boxes], R.T, grid, NEAR, FAR)
    rel32 = rel.float()
    t, hit = raycast.trace_tiles(dirs, rel32, near_boxes[keep], rect[keep], raycast.ground_t(oz, dirs, FAR))
    hit = torch.where(hit >= 0, hit, torch.where(torch.isfinite(t), GROUND, SKY))
    depth = torch.where(hit == SKY, torch.zeros_like(t), t)
    hit, t, dirs = hit.reshape(-1), t.reshape(-1), dirs.reshape(-1, 3)  # tiles of an odd size: not contiguous
    axis, _ = _faces(dirs, hit, rel32, oz)

    # Pixels whose 3x3 neighbourhood sees one face: one prefiltered sample; edges: s x s traced samples.
    key = ((hit + 2) * 3 + axis).float().view(1, 1, height, width)
    if s > 1:
        same = (F.max_pool2d(key, 3, 1, 1) == -F.max_pool2d(-key, 3, 1, 1)).view(-1)
    else:
        same = torch.ones_like(hit, dtype=torch.bool)
    inner, edge = same.nonzero().squeeze(1), (~same).nonzero().squeeze(1)
    g = (torch.arange(s, dtype=torch.float64, device=dev) + 0.5) / s - 0.5
    off_v, off_u = torch.meshgrid(g, g, indexing="ij")
    d_e = _pixel_dirs(
        K,
        R,
        (edge % width)[:, None] + off_u.reshape(1, -1),
        (edge // width)[:, None] + off_v.reshape(1, -1),
        distortion,
    )
    # A sub-sample lies between its pixel's centre and the 3 neighbouring centres of its quadrant.
    pad = F.pad(hit.view(1, 1, height, width).float(), (1, 1, 1, 1), value=SKY)[0, 0].long()
    row, col = (edge // width + 1)[:, None], (edge % width + 1)[:, None]
    su, sv = torch.sign(off_u).long().view(1, -1), torch.sign(off_v).long().view(1, -1)
    cand = torch.stack(
        [pad[row, col].expand(-1, S), pad[row + sv, col], pad[row, col + su], pad[row + sv, col + su]], -1
    )  # (E, S, 4) ids seen around each sub-sample
    b = rel32[cand.clamp_min(0)]  # (E, S, 4, 6)
    tb = raycast.slab(b[..., :3], b[..., 3:], raycast.safe_inverse(d_e)[:, :, None])
    tb = torch.where(cand >= 0, tb, torch.full_like(tb, float("inf")))
    tmin, arg = tb.min(-1)
    tg = raycast.ground_t(oz, d_e, FAR)
    h_e = torch.where(
        tmin < tg, cand.gather(2, arg[..., None]).squeeze(2), torch.where(torch.isfinite(tg), GROUND, SKY)
    )
    d_e, h_e, t_e = d_e.reshape(-1, 3), h_e.reshape(-1), torch.minimum(tmin, tg).reshape(-1)
    a_e, _ = _faces(d_e, h_e, rel32, oz)

    focal = float(K[0, 0] + K[1, 1]) / 2
    pix = torch.cat([inner, edge.repeat_interleave(S)])
    colour = _shade_samples(
        world,
        o,
        torch.cat([dirs[inner], d_e]),
        torch.cat([hit[inner], h_e]),
        torch.cat([t[inner], t_e]),
        torch.cat([axis[inner], a_e]),
        torch.cat([torch.full_like(t[inner], focal), torch.full_like(t_e, focal * s)]),
    )
    weight = torch.cat([torch.ones_like(t[inner]), torch.full_like(t_e, 1.0 / S)])
    image = torch.zeros(height * width, 3, device=dev).index_add_(0, pix, colour * weight[:, None])
    return image.clamp(0, 1).T.reshape(3, height, width).contiguous(), depth


def _shade_samples(world, o, d, hit, t, axis, focal):
    """Colours (N, 3) of samples along world rays d (N, 3) from o with hits (N,), z-depth t (N,), face axis
    (N,) and the focal length in sample units (N,) that sets each sample's footprint."""
    colour = torch.empty_like(d)
    is_sky = hit == SKY
    i = is_sky.nonzero().squeeze(1)
    colour[i] = sky(d[i], 1.0 / focal[i])
    i = (~is_sky).nonzero().squeeze(1)
    di, ai, ti = d[i], axis[i], t[i]
    p = o.float() + ti[:, None] * di
    da = di.gather(1, ai[:, None]).squeeze(1)
    normal = -torch.sign(da)[:, None] * F.one_hot(ai, 3).float()
    dn = di.norm(dim=1)
    colour[i] = shade(world, hit[i], ai, p, normal, footprint(ti, dn, da.abs() / dn, focal[i]))
    return colour
