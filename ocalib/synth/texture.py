"""Procedural, anti-aliased, Lambertian surface colours: a function of the 3D surface point only.

Everything is evaluated analytically from the world point (so every view sees the same colour):
band-limited fractal value noise (octaves finer than the sample footprint fade to their mean) and
box-filtered periodic patterns (windows, bricks, tiles, road markings). ``fp`` is the footprint of
one sample on the surface in metres; it only removes detail the sample cannot resolve.

Convention: world frame of :mod:`ocalib.synth.world` (z up); colours in [0, 1], shape (N, 3).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor

from ocalib.synth.world import BUILDING, CAR, CRATE, GLASS, KERB, PAVE, PAVEMENT, PITCH, POLE, ROAD

GROUND, SKY = -1, -2
SUN = (0.45, 0.35, 0.82)
_TABLE_SIZE = 256


def _table(device) -> Tensor:
    """A fixed periodic 256x256 table of uniform values, padded by one row/column for wrap-around."""
    g = torch.Generator().manual_seed(20240607)
    t = torch.rand(_TABLE_SIZE, _TABLE_SIZE, generator=g)
    t = torch.cat([t, t[:1]], 0)
    return torch.cat([t, t[:, :1]], 1).to(device)


_TABLES: dict = {}


def fbm(u: Tensor, v: Tensor, fp: Tensor, freq: float, octaves: int) -> Tensor:
    """Fractal value noise at 2D coordinates (N,) in metres -> (N,) in about [-0.5, 0.5].

    Octave k has ``freq * 2**k`` cells per metre and amplitude ``0.5**k``; octaves whose cell is
    smaller than ~2-4 footprints fade to their mean (0), which is what a pixel would integrate.
    """
    dev, octaves_max = u.device, octaves
    if dev not in _TABLES:
        _TABLES[dev] = _table(dev)
    table = _TABLES[dev]
    if len(fp):  # octaves that no sample can resolve are skipped (they would be faded to 0 anyway)
        octaves = max(1, min(octaves, int(math.floor(math.log2(0.5 / max(float(fp.min()), 1e-6) / freq))) + 1))
    f = freq * 2.0 ** torch.arange(octaves, device=dev, dtype=u.dtype)[:, None]  # (O, 1)
    shift = torch.arange(octaves, device=dev, dtype=u.dtype)[:, None, None] * torch.tensor([37.3, 63.4], device=dev)
    uv = torch.stack([u, v], -1)[None] * f[:, :, None] + shift  # (O, N, 2), a different offset per octave
    grid = (torch.remainder(uv, _TABLE_SIZE) * (2.0 / _TABLE_SIZE) - 1)[:, None]  # (O, 1, N, 2)
    vals = F.grid_sample(table.expand(octaves, 1, -1, -1), grid, align_corners=True).view(octaves, -1) - 0.5
    amp = 0.5 ** torch.arange(octaves, device=dev, dtype=u.dtype)[:, None]
    total = 2.0 - 0.5 ** (octaves_max - 1)
    keep = ((0.5 - fp[None] * f) * 4).clamp(0, 1)  # 1 when cell > 4 fp, 0 when cell < 2 fp
    return (vals * amp * keep).sum(0) / total * 1.6


def box(x: Tensor, a, b, w: Tensor) -> Tensor:
    """Indicator of ``a <= x < b`` (numbers or tensors) box-filtered with width ``w`` (same units as x)."""
    w = w.clamp_min(1e-4)
    a, b = torch.as_tensor(a, device=x.device), torch.as_tensor(b, device=x.device)
    return (torch.minimum(torch.maximum(x + w / 2, a), b) - torch.minimum(torch.maximum(x - w / 2, a), b)) / w


def pulse(x: Tensor, a: float, b: float, w: Tensor) -> Tensor:
    """Period-1 pulse, 1 on ``[a, b)`` of each period (0 <= a < b <= 1), box-filtered with width ``w``."""
    w = w.clamp_min(1e-4)

    def integral(y):
        fl = torch.floor(y)
        return fl * (b - a) + (y - fl).clamp(a, b) - a

    return (integral(x + w / 2) - integral(x - w / 2)) / w


def _lerp(a: Tensor, b: Tensor, m: Tensor) -> Tensor:
    return a + (b - a) * m[:, None]


def _ground(p: Tensor, fp: Tensor) -> Tensor:
    """Asphalt with dashed centre lines, edge lines and zebra crossings (only the road is visible)."""
    x, y = p[:, 0], p[:, 1]
    lx = x - torch.round(x / PITCH) * PITCH  # signed distance to the nearest north-south centreline
    ly = y - torch.round(y / PITCH) * PITCH
    n = fbm(x, y, fp, 0.5, 8)
    asphalt = 0.30 * (1 + 0.55 * n) + 0.04 * fbm(x + 91.0, y, fp, 4.0, 4)
    paint = torch.zeros_like(x)
    for lat, along, cross in ((ly, x, lx), (lx, y, ly)):  # streets along x, then along y
        open_road = box(cross.abs(), ROAD + PAVE, PITCH, fp)
        paint = paint + open_road * box(lat, -0.08, 0.08, fp) * pulse(along / 6.0, 0.0, 0.5, fp / 6.0)
        paint = paint + open_road * box(lat.abs(), ROAD - 0.45, ROAD - 0.3, fp)
        zebra = box(cross.abs(), ROAD + 0.6, ROAD + 3.4, fp) * box(lat.abs(), 0.0, ROAD - 0.7, fp)
        paint = paint + zebra * pulse(lat / 1.0, 0.0, 0.5, fp)
    paint = paint.clamp(0, 1) * (0.85 + 0.15 * n)
    grey = asphalt + (0.85 - asphalt) * paint
    return grey[:, None] * torch.tensor([1.0, 1.0, 1.02], device=p.device)


def _building(u, v, axis, p, fp, base, par) -> Tensor:
    """Facades with a grid of windows (per-building spacing) on plaster, brick or panels; gravel roofs."""
    out = torch.empty_like(base)
    roof = (axis == 2).nonzero().squeeze(1)
    out[roof] = (0.5 * base[roof] + 0.15) * (1 + 0.6 * fbm(u[roof] + par[roof, 3], v[roof], fp[roof], 1.0, 7))[:, None]
    i = (axis != 2).nonzero().squeeze(1)
    u, v, fp, base, par = u[i], v[i], fp[i], base[i], par[i]
    sx, sz, style, off = par[:, 0], par[:, 1], par[:, 2], par[:, 3]
    wall = base * (1 + 0.35 * fbm(u + off, v, fp, 0.25, 9))[:, None]
    row = v / 0.075
    brick = (style == 1).float() * (
        1
        - pulse(row, 0.0, 0.85, fp / 0.075)
        * pulse((u + 0.12 * torch.floor(row).remainder(2)) / 0.24, 0.0, 0.94, fp / 0.24)
    )
    panel = (style == 2).float() * (1 - pulse(u / 1.2, 0.0, 0.97, fp / 1.2) * pulse(v / 0.9, 0.0, 0.97, fp / 0.9))
    wall = wall * (1 - 0.45 * (brick + panel))[:, None]
    fu, fv, upper = u / sx, v / sz, box(v, sz * 0.9, 1e4, fp)
    win = pulse(fu, 0.25, 0.75, fp / sx) * pulse(fv, 0.3, 0.8, fp / sz) * upper
    frame = pulse(fu, 0.2, 0.8, fp / sx) * pulse(fv, 0.25, 0.85, fp / sz) * upper - win
    glass = 0.14 + 0.3 * fbm(u * 0.5 + off, v * 0.5, fp * 0.5, 0.5, 6)
    glass = glass[:, None] * torch.tensor([0.8, 0.9, 1.05], device=p.device)
    out[i] = _lerp(_lerp(wall, torch.full_like(wall, 0.9), frame.clamp(0, 1) * 0.8), glass, win)
    return out


def _surface(mat, u, v, axis, p, fp, base, par) -> Tensor:
    """Albedo of one material's samples (all inputs already restricted to that material)."""
    one = torch.ones_like(u)
    if mat == PAVEMENT:
        ts = par[:, 0]
        joints = 1 - pulse(u / ts, 0.0, 0.94, fp / ts) * pulse(v / ts, 0.0, 0.94, fp / ts)
        tiles = base * (1 + 0.4 * fbm(u, v, fp, 1.0, 8) - 0.4 * joints)[:, None]
        kerb = 0.62 * (1 + 0.4 * fbm(u, v, fp, 2.0, 6) - 0.2 * box(v, KERB - 0.03, KERB, fp))[:, None] * one[:, None]
        return torch.where((axis == 2)[:, None], tiles, kerb)
    if mat == BUILDING:
        return _building(u, v, axis, p, fp, base, par)
    if mat == CAR:
        z = p[:, 2]
        body = base * (1 + 0.15 * fbm(u + par[:, 0], v, fp, 1.0, 6))[:, None]
        door = pulse(u / 1.3, 0.0, 0.97, fp / 1.3) * box(z, 0.3, 10.0, fp)
        return body * (0.25 + 0.75 * door)[:, None]
    if mat == GLASS:
        return base * (1 + 0.5 * fbm(u + par[:, 0], v, fp, 2.0, 5))[:, None]
    if mat == POLE:
        rings = pulse(v / 1.0, 0.0, 0.9, fp)
        return base * ((0.7 + 0.3 * rings) * (1 + 0.3 * fbm(u, v, fp, 4.0, 5)))[:, None]
    if mat == CRATE:
        plank = par[:, 0]
        grain = fbm(u * 0.15 + par[:, 1], v * 3.0, fp * 3.0, 4.0, 5)
        return base * ((1 + 0.5 * grain) * (0.6 + 0.4 * pulse(v / plank, 0.0, 0.9, fp / plank)))[:, None]
    raise ValueError(f"unknown material {mat}")


def sky(d: Tensor, fp: Tensor) -> Tensor:
    """Sky colour for world directions (N, 3): a horizon-to-zenith gradient with soft clouds."""
    d = d / d.norm(dim=-1, keepdim=True)
    el = d[:, 2].clamp(0, 1)
    dev = d.device
    grad = _lerp(
        torch.tensor([0.86, 0.90, 0.95], device=dev).expand_as(d),
        torch.tensor([0.35, 0.55, 0.88], device=dev).expand_as(d),
        el.sqrt(),
    )
    zc = d[:, 2].clamp_min(0.05)
    cloud = (fbm(d[:, 0] / zc, d[:, 1] / zc, fp / zc, 0.4, 6) * 2.2 + 0.1).clamp(0, 1) * (el * 8).clamp(0, 1)
    return _lerp(grad, torch.full_like(d, 0.97), cloud)


def shade(world, box_id: Tensor, axis: Tensor, p: Tensor, normal: Tensor, fp: Tensor) -> Tensor:
    """Lambertian colour (N, 3) of surface samples: ``box_id`` (N,) (-1 for the ground), hit axis (N,),
    world point (N, 3), unit normal (N, 3), footprint (N,) in metres. ``world`` is a
    :class:`~ocalib.synth.render.WorldTensors`."""
    dev = p.device
    albedo = torch.empty_like(p)
    ground = box_id == GROUND
    if ground.any():
        idx = ground.nonzero().squeeze(1)
        albedo[idx] = _ground(p[idx], fp[idx])
    # Surface coordinates: horizontal along the face and height (vertical faces), or x/y (horizontal).
    ax = axis.clamp(0, 2)
    u = torch.where(ax == 0, p[:, 1], p[:, 0])
    v = torch.where(ax == 2, p[:, 1], p[:, 2])
    mat_of = world.material[box_id.clamp_min(0)]
    for mat in torch.bincount(mat_of[~ground], minlength=1).nonzero().squeeze(1).tolist():
        idx = ((mat_of == mat) & ~ground).nonzero().squeeze(1)
        b = box_id[idx]
        albedo[idx] = _surface(mat, u[idx], v[idx], ax[idx], p[idx], fp[idx], world.albedo[b], world.params[b])
    sun = torch.tensor(SUN, device=dev)
    light = 0.58 + 0.48 * (normal @ (sun / sun.norm())).clamp_min(0)
    return (albedo * light[:, None]).clamp(0, 1)


def footprint(depth: Tensor, ray_norm: Tensor, cos_incidence: Tensor, focal: float) -> Tensor:
    """Metres on the surface covered by one sample: z-depth (N,), ray length per unit depth (N,),
    |cos| of the incidence angle (N,), focal length in samples."""
    return depth * ray_norm / (focal * cos_incidence.clamp_min(0.15))
