"""A procedural street-canyon city: a Manhattan grid of blocks made of axis-aligned boxes.

Convention: world frame x east, y north, z up (metres); the ground is the plane z = 0. Streets run
along x and y with centrelines at multiples of :data:`PITCH`; the road is ``|d| < ROAD`` from a
centreline, then a raised pavement (kerb :data:`KERB`) up to ``ROAD + PAVE``, then buildings.
Parked cars stand on the road within ``[ROAD - 2.1, ROAD - 0.3]`` of a centreline, lamp posts and
crates on the pavement, so anything that keeps within ``ROAD - 2.2`` of a centreline (or inside a
crossing) never enters geometry. Every block is generated from ``(seed, i, j)`` alone, so the
city is the same wherever a sequence goes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

PITCH = 64.0  # street centreline spacing (m)
ROAD = 5.0  # half width of the road (m)
PAVE = 3.0  # pavement width (m)
KERB = 0.15  # pavement height (m)

# Materials (the texture of a box; see ocalib.synth.texture).
PAVEMENT, BUILDING, CAR, GLASS, POLE, CRATE = range(6)


@dataclass
class World:
    """Boxes ``(P, 6)`` as ``[x0, y0, z0, x1, y1, z1]`` (float64), one material (P,), albedo (P, 3) and
    four texture parameters (P, 4) per box, and the ``seed`` that made it."""

    boxes: np.ndarray
    material: np.ndarray
    albedo: np.ndarray
    params: np.ndarray
    seed: int

    def __len__(self) -> int:
        return len(self.boxes)


class _Builder:
    def __init__(self):
        self.rows = []

    def add(self, lo, hi, material, albedo, params=(0.0, 0.0, 0.0, 0.0)):
        lo, hi = np.minimum(lo, hi), np.maximum(lo, hi)
        self.rows.append((*lo, *hi, material, *albedo, *params))

    def world(self, seed: int) -> World:
        a = np.asarray(self.rows, dtype=np.float64).reshape(-1, 14)
        return World(a[:, :6].copy(), a[:, 6].astype(np.int64), a[:, 7:10].copy(), a[:, 10:14].copy(), seed)


FACADE_COLOURS = np.array(
    [
        [0.72, 0.62, 0.52],
        [0.62, 0.36, 0.28],
        [0.78, 0.76, 0.70],
        [0.55, 0.57, 0.60],
        [0.80, 0.70, 0.50],
        [0.48, 0.40, 0.36],
        [0.70, 0.50, 0.40],
        [0.86, 0.84, 0.80],
    ]
)
CAR_COLOURS = np.array(
    [
        [0.75, 0.10, 0.10],
        [0.10, 0.20, 0.55],
        [0.85, 0.85, 0.85],
        [0.15, 0.15, 0.15],
        [0.45, 0.47, 0.50],
        [0.10, 0.40, 0.20],
        [0.85, 0.65, 0.10],
        [0.55, 0.55, 0.60],
    ]
)


def _split(rng, length, lo, hi):
    """Random widths in [lo, hi] that sum to ``length``."""
    widths = []
    while length - sum(widths) > hi:
        widths.append(rng.uniform(lo, hi))
    widths.append(length - sum(widths))
    return np.cumsum([0.0, *widths])


def _block(b: _Builder, seed: int, i: int, j: int) -> None:
    rng = np.random.default_rng([seed, i + 10_000, j + 10_000])
    x0, y0 = i * PITCH, j * PITCH
    inner0, inner1 = ROAD + PAVE, PITCH - ROAD - PAVE
    b.add(
        (x0 + ROAD, y0 + ROAD, 0),
        (x0 + PITCH - ROAD, y0 + PITCH - ROAD, KERB),
        PAVEMENT,
        rng.uniform(0.55, 0.7) * np.array([1.0, 0.97, 0.92]),
        (rng.uniform(0.4, 0.7), rng.uniform(0, 50), 0, 0),
    )
    # Two rows of buildings (south half, north half), each split along x; end buildings face the x streets.
    mid = PITCH / 2 + rng.uniform(-4, 4)
    for y_face, y_back in ((inner0, mid), (inner1, mid)):
        cuts = _split(rng, inner1 - inner0, 7.0, 16.0) + inner0
        for k in range(len(cuts) - 1):
            xa, xb = cuts[k], cuts[k + 1]
            if k == 0:
                xa += rng.choice([0.0, rng.uniform(0, 2)])
            if k == len(cuts) - 2:
                xb -= rng.choice([0.0, rng.uniform(0, 2)])
            setback = rng.choice([0.0, 0.0, rng.uniform(0.3, 2.5)])
            yf = y_face + setback if y_face < y_back else y_face - setback
            height = rng.uniform(7, 26) if rng.random() < 0.85 else rng.uniform(26, 40)
            params = (rng.uniform(2.4, 4.0), rng.uniform(3.0, 3.6), rng.integers(0, 3), rng.uniform(0, 100))
            b.add(
                (x0 + xa, y0 + yf, 0),
                (x0 + xb, y0 + y_back, height),
                BUILDING,
                FACADE_COLOURS[rng.integers(len(FACADE_COLOURS))] * rng.uniform(0.85, 1.1),
                params,
            )
    for side in range(4):
        _street_side(b, rng, x0, y0, side)


def _street_side(b: _Builder, rng, x0, y0, side):
    """Parked cars, lamp posts and crates along one of the block's four sides.

    A side is described in local coordinates: ``s`` along the kerb, ``d`` distance from the street
    centreline (growing into the block).
    """

    def place(s0, s1, d0, d1, z0, z1, *args):
        if side == 0:  # south street (y = y0), s along +x
            b.add((x0 + s0, y0 + d0, z0), (x0 + s1, y0 + d1, z1), *args)
        elif side == 1:  # north street (y = y0 + PITCH)
            b.add((x0 + s0, y0 + PITCH - d0, z0), (x0 + s1, y0 + PITCH - d1, z1), *args)
        elif side == 2:  # west street (x = x0), s along +y
            b.add((x0 + d0, y0 + s0, z0), (x0 + d1, y0 + s1, z1), *args)
        else:  # east street
            b.add((x0 + PITCH - d0, y0 + s0, z0), (x0 + PITCH - d1, y0 + s1, z1), *args)

    s = ROAD + PAVE + 2 + rng.uniform(0, 6)
    while s < PITCH - ROAD - PAVE - 6.5:  # parked cars
        length = rng.uniform(3.8, 4.8)
        if rng.random() < 0.55:
            colour = CAR_COLOURS[rng.integers(len(CAR_COLOURS))]
            d0 = ROAD - rng.uniform(1.9, 2.1)
            height = rng.uniform(0.85, 1.0)
            params = (rng.uniform(0, 100), 0, 0, 0)
            place(s, s + length, d0, ROAD - 0.3, 0.0, height, CAR, colour, params)
            c0, c1 = s + length * rng.uniform(0.2, 0.3), s + length * rng.uniform(0.68, 0.8)
            place(
                c0,
                c1,
                d0 + 0.12,
                ROAD - 0.42,
                height,
                height + rng.uniform(0.4, 0.55),
                GLASS,
                colour * 0.35 + 0.05,
                params,
            )
        s += length + rng.uniform(0.8, 4.0)
    s = ROAD + PAVE + rng.uniform(2, 10)
    while s < PITCH - ROAD - PAVE:  # lamp posts with an arm over the road
        height = rng.uniform(5.5, 7.5)
        grey = rng.uniform(0.25, 0.5) * np.ones(3)
        place(s, s + 0.16, ROAD + 0.4, ROAD + 0.56, KERB, height, POLE, grey, (rng.uniform(0, 100), 0, 0, 0))
        place(s - 0.05, s + 0.21, ROAD - 1.2, ROAD + 0.4, height - 0.2, height, POLE, grey * 0.8, (0, 0, 0, 0))
        s += rng.uniform(14, 22)
    for _ in range(rng.integers(0, 4)):  # crates, bins and boxes by the facades
        size = rng.uniform(0.4, 1.4, 3)
        s = rng.uniform(ROAD + PAVE + 1, PITCH - ROAD - PAVE - 2)
        d = ROAD + PAVE - size[1] - rng.uniform(0.05, 0.5)
        place(
            s,
            s + size[0],
            d,
            d + size[1],
            KERB,
            KERB + size[2],
            CRATE,
            rng.uniform(0.35, 0.75) * np.array([1.0, 0.8, 0.55]),
            (rng.uniform(0.08, 0.2), rng.uniform(0, 100), 0, 0),
        )


def make_world(seed: int, xy_min, xy_max) -> World:
    """All blocks touching the rectangle ``[xy_min, xy_max]`` (metres, world x/y)."""
    i0, j0 = np.floor(np.asarray(xy_min, dtype=float) / PITCH).astype(int)
    i1, j1 = np.floor(np.asarray(xy_max, dtype=float) / PITCH).astype(int)
    b = _Builder()
    for i in range(i0, i1 + 1):
        for j in range(j0, j1 + 1):
            _block(b, seed, i, j)
    return b.world(seed)
