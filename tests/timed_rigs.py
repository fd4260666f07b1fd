"""Synthetic two-camera rigs on their own clocks: smooth hand-held-like motion sampled at each camera's rate, for the
tests of timestamp association and clock-offset estimation."""

from __future__ import annotations

import numpy as np


def rotvec_to_matrix(v: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation vectors (N, 3) -> rotation matrices (N, 3, 3)."""
    theta = np.linalg.norm(v, axis=-1)[:, None, None]
    k = v / np.maximum(theta[:, :, 0], 1e-300)
    K = np.zeros((len(v), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    K = K - K.transpose(0, 2, 1)
    return np.eye(3) + np.sin(theta) * K + (1 - np.cos(theta)) * K @ K


class SmoothMotion:
    """Camera-0 pose as a smooth random function of true time: rotation vector and position are sums of
    sinusoids of 0.05-3 Hz (hand-held-like motion; ``rotation=0`` gives pure translation)."""

    def __init__(self, seed: int, n_waves: int = 20, rotation: float = 0.15):
        rng = np.random.default_rng(seed)
        self.freq = rng.uniform(0.05, 3.0, (n_waves, 1))
        self.phase = rng.uniform(0, 2 * np.pi, (n_waves, 6))
        self.amp = rng.normal(0, 1, (n_waves, 6)) * np.array([rotation] * 3 + [0.5] * 3)

    def __call__(self, t: np.ndarray) -> np.ndarray:
        """True times (N,) -> camera-to-world poses (N, 4, 4)."""
        wave = np.sin(2 * np.pi * self.freq[None] * np.asarray(t)[:, None, None] + self.phase[None])
        s = (self.amp[None] * wave).sum(1)
        T = np.zeros((len(t), 4, 4))
        T[:, :3, :3] = rotvec_to_matrix(s[:, :3])
        T[:, :3, 3] = s[:, 3:]
        T[:, 3, 3] = 1
        return T


def make_rig(seed=0, duration=60.0, rate0=30.0, rate1=20.0, jitter1=0.0, start1=0.0, rotation=0.15, noise=0.0):
    """Two cameras of one rig -> (true times0 (N0,), poses0 (N0, 4, 4), true times1 (N1,), poses1 (N1, 4, 4)).

    Camera 1 = camera 0 @ a fixed extrinsic, in its own world frame, sampled at its own rate (times
    jittered by up to ``jitter1`` of its frame period), over [start1, duration] of true time. ``noise``:
    rotation noise per pose and axis, radians.
    """
    rng = np.random.default_rng(seed + 1000)
    motion = SmoothMotion(seed, rotation=rotation)
    t0 = np.arange(0, duration, 1 / rate0)
    t1 = np.arange(start1, duration, 1 / rate1)
    t1 = t1 + rng.uniform(-jitter1, jitter1, len(t1)) / rate1
    X, W = np.eye(4), np.eye(4)
    X[:3, :3], X[:3, 3] = rotvec_to_matrix(rng.normal(0, 1, (1, 3)))[0], rng.normal(0, 1, 3)
    W[:3, :3], W[:3, 3] = rotvec_to_matrix(rng.normal(0, 1, (1, 3)))[0], rng.normal(0, 5, 3)
    p0, p1 = motion(t0), W @ motion(t1) @ X
    for p in (p0, p1):
        p[:, :3, :3] = p[:, :3, :3] @ rotvec_to_matrix(rng.normal(0, noise, (len(p), 3)))
    return t0, p0, t1, p1
