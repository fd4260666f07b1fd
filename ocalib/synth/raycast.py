"""Vectorised ray casting against axis-aligned boxes and the ground plane.

A view's rays are cut into screen tiles; every box is projected (clipped at the near plane) to a
pixel rectangle, and only (box, tile) pairs that overlap are tested, all in one batch, then reduced
to the nearest hit per ray with ``scatter_reduce``. Through a lens (:mod:`ocalib.data.distortion`) the
rectangles come from the rays' bounds in the normalised plane, tile by tile. Coordinates are relative
to the camera centre (float32 is then precise to ~1e-5 m near the camera).

Convention: ray directions are world-frame vectors whose camera-frame z component is 1, so the ray
parameter ``t`` of a hit *is* its z-depth. Hit ids: box index >= 0, :data:`GROUND` (-1), :data:`SKY` (-2).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from ocalib.synth.texture import GROUND, SKY

_CORNERS = torch.tensor([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)])
_EDGES = torch.tensor([[a, b] for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1])


def box_extents(rel: Tensor, Rt: Tensor, K: Tensor, near: float):
    """Bounds of the projections by K (3, 3) of boxes (their parts beyond the near plane) seen by a camera at the
    origin; rel (P, 6) float64 box bounds relative to the camera centre, Rt (3, 3) world-to-camera rotation.
    Returns (seen (P,) bool: some part beyond the near plane, extent (P, 4) ``[u0, v0, u1, v1]``, dist (P,) metres
    from the camera to the box)."""
    lo, hi = rel[:, :3], rel[:, 3:]
    corners = torch.where(_CORNERS.to(rel.device).bool(), hi[:, None], lo[:, None]) @ Rt.T  # (P, 8, 3)
    a, b = corners[:, _EDGES[:, 0]], corners[:, _EDGES[:, 1]]  # (P, 12, 3)
    s = (near - a[..., 2]) / (b[..., 2] - a[..., 2])
    cut = a + s.unsqueeze(-1).nan_to_num(0) * (b - a)
    pts = torch.cat([corners, cut], 1)
    valid = torch.cat([corners[..., 2] >= near, (s > 0) & (s < 1)], 1)
    z = pts[..., 2].clamp_min(near)
    u = K[0, 0] * pts[..., 0] / z + K[0, 2]
    v = K[1, 1] * pts[..., 1] / z + K[1, 2]
    inf = torch.tensor(float("inf"), dtype=rel.dtype, device=rel.device)
    u0, u1 = torch.where(valid, u, inf).amin(1), torch.where(valid, u, -inf).amax(1)
    v0, v1 = torch.where(valid, v, inf).amin(1), torch.where(valid, v, -inf).amax(1)
    dist = torch.maximum(torch.maximum(lo, -hi), torch.zeros_like(lo)).norm(dim=1)
    return valid.any(1), torch.stack([u0, v0, u1, v1], 1), dist


def screen_rects(rel: Tensor, Rt: Tensor, K: Tensor, height: int, width: int, near: float, far: float):
    """Pixel rectangles of boxes seen by a pinhole camera at the origin.

    rel (P, 6) float64 box bounds relative to the camera centre; Rt (3, 3) world-to-camera rotation;
    K (3, 3). Returns (keep (P,) bool, rect (P, 4) long ``[u0, v0, u1, v1]`` inclusive, clipped to the image).
    """
    seen, extent, dist = box_extents(rel, Rt, K, near)
    u0, v0, u1, v1 = extent.unbind(1)
    keep = seen & (u1 >= -1) & (u0 <= width) & (v1 >= -1) & (v0 <= height) & (dist < far)
    rect = torch.stack([u0 - 1, v0 - 1, u1 + 1, v1 + 1], 1).clamp(-1, 1e6).nan_to_num(0)
    rect = torch.stack([rect[:, 0].ceil(), rect[:, 1].ceil(), rect[:, 2].floor(), rect[:, 3].floor()], 1).long()
    rect[:, 0::2] = rect[:, 0::2].clamp(0, width - 1)
    rect[:, 1::2] = rect[:, 1::2].clamp(0, height - 1)
    return keep, rect


def lens_rects(rel: Tensor, Rt: Tensor, grid: Tensor, near: float, far: float, tile: int = 4):
    """Pixel rectangles of boxes seen through a lens, for :func:`trace_tiles`: ``grid`` (H, W, 2) the normalised
    (undistorted) coordinates of the pixel-centre rays. A box's rectangle spans the tiles whose rays (with their
    neighbours') have bounds in the normalised plane that meet its projection's (conservative: a ray hits the box only
    inside its projection). rel, Rt as :func:`screen_rects`. Returns (keep (P,) bool, rect (P, 4) long inclusive)."""
    H, W, _ = grid.shape
    seen, extent, dist = box_extents(rel, Rt, torch.eye(3, dtype=rel.dtype, device=rel.device), near)
    g = F.pad(grid.permute(2, 0, 1)[None], (1, 1, 1, 1), mode="replicate")
    hi = F.max_pool2d(F.max_pool2d(g, 3, 1), tile, tile, ceil_mode=True)[0]  # (2, ty, tx): the tiles' bounds
    lo = -F.max_pool2d(F.max_pool2d(-g, 3, 1), tile, tile, ceil_mode=True)[0]
    meets = (
        (extent[:, 0, None, None] <= hi[0]) & (extent[:, 2, None, None] >= lo[0])
        & (extent[:, 1, None, None] <= hi[1]) & (extent[:, 3, None, None] >= lo[1])
    )  # (P, ty, tx)  # fmt: skip
    rows, cols = meets.any(2), meets.any(1)
    keep = seen & rows.any(1) & (dist < far)
    first = lambda m: m.float().argmax(1)  # noqa: E731
    last = lambda m: m.shape[1] - 1 - m.flip(1).float().argmax(1)  # noqa: E731
    rect = torch.stack([first(cols) * tile, first(rows) * tile, last(cols) * tile, last(rows) * tile], 1)
    return keep, torch.minimum(rect, torch.tensor([W - 1, H - 1, W - 1, H - 1], device=rect.device))


def slab(lo: Tensor, hi: Tensor, inv: Tensor) -> Tensor:
    """Entry ``t`` of rays from the origin into boxes (inf on a miss). Broadcasting shapes (..., 3)."""
    t1, t2 = lo * inv, hi * inv
    tn = torch.minimum(t1, t2).amax(-1)
    tf = torch.maximum(t1, t2).amin(-1)
    return torch.where((tn <= tf) & (tn > 0), tn, torch.full_like(tn, float("inf")))


def safe_inverse(d: Tensor) -> Tensor:
    """1 / d with zero components replaced by a tiny value of the same sign convention (+)."""
    return 1.0 / torch.where(d.abs() < 1e-12, torch.full_like(d, 1e-12), d)


def ground_t(oz: float, d: Tensor, far: float) -> Tensor:
    """Ray parameter of the ground plane z = 0 for rays from height ``oz`` (inf if none within ``far``)."""
    t = -oz / d[..., 2]
    return torch.where((d[..., 2] < 0) & (t < far), t, torch.full_like(t, float("inf")))


def trace_tiles(dirs: Tensor, rel32: Tensor, boxes: Tensor, rect: Tensor, t_init: Tensor, tile: int = 4):
    """Nearest box hit of an image of rays.

    dirs (H, W, 3) float32 world directions; rel32 (P, 6) float32 relative bounds; boxes (B,) indices of
    the boxes to test with rect (B, 4) their pixel rectangles; t_init (H, W) the best hit so far (ground).
    Returns (t (H, W), box (H, W) long, -1 where no box beats t_init).
    """
    H, W, _ = dirs.shape
    dev = dirs.device
    nty, ntx = -(-H // tile), -(-W // tile)
    Hp, Wp = nty * tile, ntx * tile
    inv = torch.ones(3, Hp, Wp, device=dev)
    inv[:, :H, :W] = safe_inverse(dirs).permute(2, 0, 1)
    inv = inv.view(3, nty, tile, ntx, tile).permute(0, 1, 3, 2, 4).reshape(3, nty * ntx, tile * tile)
    ray_id = torch.arange(Hp * Wp, device=dev).view(nty, tile, ntx, tile).permute(0, 2, 1, 3).reshape(nty * ntx, -1)
    best = torch.full((Hp, Wp), float("inf"), device=dev)
    best[:H, :W] = t_init
    best = best.view(-1)
    hit_box = torch.full((Hp * Wp,), -1, dtype=torch.long, device=dev)
    if len(boxes) == 0:
        return best.view(Hp, Wp)[:H, :W], hit_box.view(Hp, Wp)[:H, :W]
    tx0, ty0, tx1, ty1 = (rect // tile).unbind(1)
    nx = tx1 - tx0 + 1
    count = nx * (ty1 - ty0 + 1)
    pair_box = torch.repeat_interleave(torch.arange(len(boxes), device=dev), count)
    k = torch.arange(len(pair_box), device=dev) - torch.repeat_interleave(torch.cumsum(count, 0) - count, count)
    pair_tile = (ty0[pair_box] + k // nx[pair_box]) * ntx + tx0[pair_box] + k % nx[pair_box]
    bounds = rel32[boxes][pair_box]  # (M, 6)
    tn = tf = None
    for a in range(3):  # slab test axis by axis on (M, tile*tile)
        ia = inv[a][pair_tile]
        t1, t2 = bounds[:, a : a + 1] * ia, bounds[:, a + 3 : a + 4] * ia
        near, far = torch.minimum(t1, t2), torch.maximum(t1, t2)
        tn, tf = (near, far) if tn is None else (torch.maximum(tn, near), torch.minimum(tf, far))
    t = torch.where((tn <= tf) & (tn > 0), tn, torch.full_like(tn, float("inf")))
    rid = ray_id[pair_tile]
    best.scatter_reduce_(0, rid.reshape(-1), t.reshape(-1), "amin")
    win = (t == best[rid]) & torch.isfinite(t)
    hit_box.scatter_reduce_(0, rid[win], boxes[pair_box].unsqueeze(1).expand_as(t)[win], "amax")  # ties: larger id
    return best.view(Hp, Wp)[:H, :W], hit_box.view(Hp, Wp)[:H, :W]


def hit_axis(dirs: Tensor, lo: Tensor, hi: Tensor) -> Tensor:
    """Axis (0, 1, 2) of the face through which rays (N, 3) enter boxes with relative bounds (N, 3)."""
    inv = safe_inverse(dirs)
    return torch.minimum(lo * inv, hi * inv).argmax(-1)


__all__ = [
    "GROUND",
    "SKY",
    "box_extents",
    "screen_rects",
    "lens_rects",
    "slab",
    "safe_inverse",
    "ground_t",
    "trace_tiles",
    "hit_axis",
]
