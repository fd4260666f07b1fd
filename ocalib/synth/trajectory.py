"""Rig trajectories through the street grid of :mod:`ocalib.synth.world`.

All three follow a random route along street centrelines (straight on, left or right at each
crossing, quarter-circle turns of radius :data:`TURN_RADIUS` inside the crossing) and differ in how
the rig moves around it:

* ``drive``: a car in the right-hand lane: planar motion with small pitch/roll from the road surface
  and from cornering, slowing down for turns, cruise speed changing between blocks.
* ``handheld``: a person walking down the road: walking speed, step bounce and sway, and smooth
  6-DoF wandering of the view direction (yaw +-20 deg, pitch +-8 deg, roll +-5 deg).
* ``lds``: the paper's linear dynamic system: every degree of freedom of the offset from the route
  (lateral, vertical, along, roll, pitch, yaw) is a noise-driven damped oscillator,
  ``x_{t+1} = A x_t + B w_t``, so all rotation axes are excited (large, generic 6-DoF motion).

Offsets are clipped so the rig stays within ``ROAD - 2.2`` m of the centreline (clear of parked
cars) at a height between 0.5 and 3 m: the cameras never enter geometry.

Convention: returns camera 0's poses, camera-to-world (N, 4, 4) float64, world frame z up; the rig
frame is x forward, y left, z up, and camera 0 (x right, y down, z forward) looks along the rig's x.
"""

from __future__ import annotations

import math

import numpy as np

from ocalib.errors import InputError
from ocalib.geometry.se3 import rotation_angle_deg
from ocalib.synth.world import PITCH, ROAD

TURN_RADIUS = 9.0
# A trajectory whose camera 0 turns less than this (deg) from its first orientation is all but straight: the
# rotation between the cameras is not observable from its motion (the hand-eye constraint needs rotations)
STRAIGHT_DEG = 5.0
R_RIG_CAM = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # camera axes in the rig frame
_DIRS = np.array([[1, 0], [0, 1], [-1, 0], [0, -1]])  # E, N, W, S


def route(rng, length: float, step: float = 0.05):
    """A route along the street grid -> (xy (M, 2), heading (M,), curvature (M,)), samples ``step`` m apart."""
    pos, node, d, turn_in = np.array([rng.uniform(0.3, 0.6) * PITCH, 0.0]), np.array([PITCH, 0.0]), 0, 0
    xy, heading, kappa = [], [], []
    while step * sum(map(len, xy)) < length:
        turn = int(rng.choice([0, 0, 1, -1]))  # straight on twice as often as left (+1) or right (-1)
        h0 = math.atan2(_DIRS[d][1], _DIRS[d][0])
        start = pos + _DIRS[d] * (TURN_RADIUS if turn_in else 0.0)
        end = node - _DIRS[d] * (TURN_RADIUS if turn else 0.0)
        n = max(int(np.linalg.norm(end - start) / step), 1)
        xy.append(start + (end - start) * (np.arange(n) / n)[:, None])
        heading.append(np.full(n, h0))
        kappa.append(np.zeros(n))
        if turn:  # quarter circle tangent to both centrelines
            centre = end + turn * TURN_RADIUS * np.array([-math.sin(h0), math.cos(h0)])
            m = int(TURN_RADIUS * math.pi / 2 / step)
            h = h0 + turn * (math.pi / 2) * np.arange(m) / m
            xy.append(centre + turn * TURN_RADIUS * np.stack([np.sin(h), -np.cos(h)], 1))
            heading.append(h)
            kappa.append(np.full(m, turn / TURN_RADIUS))
        pos, d, turn_in = node.copy(), (d + turn) % 4, turn
        node = node + _DIRS[d] * PITCH
    return np.concatenate(xy), np.unwrap(np.concatenate(heading)), np.concatenate(kappa)


def _at(s_query, s, *arrays):
    return [np.interp(s_query, s, a) for a in arrays]


def _smooth_noise(rng, t, amplitude, periods=(2.0, 4.0, 9.0)):
    """A smooth random signal (sum of sines with random phases) with peak about ``amplitude``."""
    out = np.zeros_like(t)
    for p in periods:
        out += np.sin(2 * math.pi * t / (p * rng.uniform(0.8, 1.25)) + rng.uniform(0, 2 * math.pi))
    return amplitude * out / len(periods)


def _pose(xy, z, yaw, pitch, roll):
    """Camera-0 poses from rig position (N, 2), height (N,) and yaw/pitch/roll (N,) (z-y-x, radians)."""
    cy, sy, cp, sp, cr, sr = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    R = np.stack(
        [
            np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
            np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
            np.stack([-sp, cp * sr, cp * cr], -1),
        ],
        -2,
    )
    T = np.tile(np.eye(4), (len(z), 1, 1))
    T[:, :3, :3] = R @ R_RIG_CAM
    T[:, :2, 3] = xy
    T[:, 2, 3] = z
    return T


def _speed_profile(s, kappa, cruise_of_s, a_lat=2.0, accel=1.5, decel=2.5):
    """Speed (M,) along the route: cruise speed, limited in turns, with bounded (de)acceleration."""
    v = np.minimum(cruise_of_s, np.sqrt(a_lat / np.maximum(np.abs(kappa), 1e-6)))
    ds = np.diff(s, prepend=s[0])
    for i in range(1, len(v)):
        v[i] = min(v[i], math.sqrt(v[i - 1] ** 2 + 2 * accel * ds[i]))
    for i in range(len(v) - 2, -1, -1):
        v[i] = min(v[i], math.sqrt(v[i + 1] ** 2 + 2 * decel * ds[i + 1]))
    return v


def _march(s, v, frames, dt, substeps=10):
    """Arc length at each frame time, integrating ds/dt = v(s)."""
    out = np.zeros(frames)
    cur = 0.0
    for k in range(frames):
        out[k] = cur
        for _ in range(substeps):
            cur += np.interp(cur, s, v) * dt / substeps
    return out


def trajectory(
    kind: str,
    frames: int,
    frame_rate: float,
    seed: int,
    speed: float | None = None,
    height: float | None = None,
    at: np.ndarray | None = None,
) -> np.ndarray:
    """Camera-0 poses (frames, 4, 4) float64 for ``kind`` in drive | handheld | lds.

    at: (M,) frame indices, fractional and past the last frame allowed, where to sample instead (-> (M, 4, 4)):
    between frames the rig's position and angles are linear in time. ``at = arange(frames)`` gives the default.
    """
    if at is not None:
        at = np.asarray(at, dtype=np.float64)
        if not (np.isfinite(at).all() and at.min() >= 0):
            raise InputError("trajectory: sample indices must be finite and >= 0")
    defaults = {"drive": (8.0, 1.65), "handheld": (1.4, 1.5), "lds": (3.0, 1.5)}
    if kind not in defaults:
        raise InputError(f"unknown trajectory kind {kind!r} (kinds: {', '.join(defaults)})")
    speed = float(defaults[kind][0] if speed is None else speed)
    height = float(defaults[kind][1] if height is None else height)
    if not (0 < speed <= 40) or not (0.5 <= height <= 3.0):
        raise InputError(f"trajectory: speed must be in (0, 40] m/s and height in [0.5, 3] m, got {speed}, {height}")

    def rng(stream):  # one random stream per component: a longer sequence starts like a shorter one
        return np.random.default_rng([seed, 7, stream])

    dt = 1.0 / frame_rate
    xy, heading, kappa = route(rng(0), speed * 1.3 * frames * dt + 2 * PITCH)
    frames = frames if at is None else max(frames, int(np.ceil(at.max())) + 1)  # the same route, driven on
    channels = _channels(kind, frames, dt, speed, height, xy, heading, kappa, rng)
    if at is not None:
        channels = [np.interp(at, np.arange(frames), c) for c in channels]
    return _pose(np.stack(channels[:2], 1), *channels[2:])


def _channels(kind, frames, dt, speed, height, xy, heading, kappa, rng) -> list[np.ndarray]:
    """The rig's x, y, z, yaw, pitch, roll (frames,) each along the route ``xy, heading, kappa``."""
    lateral = {"drive": -1.5, "handheld": 0.0, "lds": 0.0}[kind]
    xy = xy + lateral * np.stack([-np.sin(heading), np.cos(heading)], 1)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
    block = np.floor(s / PITCH)
    cruise = speed * rng(1).uniform(0.6, 1.25, int(block.max()) + 1)[block.astype(int)]
    v = _speed_profile(s, kappa, cruise, a_lat=2.0 if kind == "drive" else 0.5)
    sf = _march(s, v, frames, dt)
    x, y, h, k, vel = _at(sf, s, xy[:, 0], xy[:, 1], heading, kappa, v)
    t = np.arange(frames) * dt
    rng = rng(2)
    if kind == "drive":
        pitch = 0.008 * np.sin(2 * math.pi * sf / 23.0 + rng.uniform(0, 6)) + 0.004 * np.sin(2 * math.pi * sf / 6.1)
        roll = -0.012 * vel**2 * k + 0.005 * np.sin(2 * math.pi * sf / 17.0 + rng.uniform(0, 6))
        z = height + 0.01 * np.sin(2 * math.pi * sf / 9.0)
        return [x, y, z, h, pitch, roll]
    left = np.stack([-np.sin(h), np.cos(h)], 1)
    if kind == "handheld":
        step_hz = 1.8 * rng.uniform(0.9, 1.1)
        phase = 2 * math.pi * np.cumsum(np.full(frames, step_hz * dt) * np.minimum(vel / speed, 1.0))
        side = np.clip(_smooth_noise(rng, t, 1.0, (6.0, 11.0)) + 0.04 * np.sin(phase / 2), -1.5, 1.5)
        z = height + 0.03 * np.sin(phase) + _smooth_noise(rng, t, 0.08, (5.0, 8.0))
        yaw = h + _smooth_noise(rng, t, math.radians(20))
        pitch = _smooth_noise(rng, t, math.radians(8)) + 0.01 * np.sin(phase)
        roll = _smooth_noise(rng, t, math.radians(5)) + 0.01 * np.sin(phase / 2)
        xy = np.stack([x, y], 1) + side[:, None] * left
        return [xy[:, 0], xy[:, 1], z, yaw, pitch, roll]
    # lds: x_{t+1} = A x_t + B w_t per degree of freedom, state (offset, rate), stiffness w0, damping c.
    sigma = np.array([1.0, 0.3, 0.5, math.radians(25), math.radians(15), math.radians(30)])
    w0, c = 2 * math.pi / 4.0, 0.6
    A = np.array([[1.0, dt], [-(w0**2) * dt, 1 - c * dt]])
    state = np.zeros((6, 2))
    out = np.zeros((frames, 6))
    for i in range(frames):
        out[i] = state[:, 0]
        state = state @ A.T + np.stack([np.zeros(6), sigma * w0 * math.sqrt(2 * c * dt) * rng.standard_normal(6)], 1)
    lat = np.clip(out[:, 0], -(ROAD - 2.2), ROAD - 2.2)
    z = np.clip(height + out[:, 1], 0.5, 3.0)
    fwd = np.stack([np.cos(h), np.sin(h)], 1)
    pos = np.stack([x, y], 1) + lat[:, None] * left + np.clip(out[:, 2], -1, 1)[:, None] * fwd
    return [pos[:, 0], pos[:, 1], z, h + out[:, 5], out[:, 4], out[:, 3]]


def turned_deg(poses: np.ndarray) -> float:
    """The largest rotation (deg) of the poses (N, 4, 4) from the first one's orientation: how far the camera turns."""
    return float(rotation_angle_deg(poses[0, :3, :3].T @ poses[:, :3, :3]).max())
