"""OpenCV's hand-eye test protocol (``modules/calib3d/test/test_hand_eye_calibration.cpp``), as data.

A trial: a hand-eye transform ``X`` with a random angle in 10-50 deg and translations of 0.05-0.5 per axis, a
target at 5-85 deg and 0.5-3.5, and gripper poses at 5-45 deg and 0.5-1.5 (random signs, unnormalised random
axes); noise N(0, 0.002) on the target-to-camera rotation vector and N(0, 0.005) on its translation, N(0, 0.001)
on both parts of gripper-to-base.

Convention (OpenCV's): ``X = T_cam2gripper``, poses ``T_gripper2base`` and ``T_target2cam``; as a rig, the
gripper is camera 0 (pose ``T_gripper2base``), the camera is camera 1 (pose ``T_target2cam^-1``, its world the
target), and ``X = T_cam0_cam1``.
"""

from __future__ import annotations

import math

import cv2
import numpy as np


def generate_pose(rng, theta, t):
    """OpenCV's ``generatePose`` with random signs: (4, 4). theta, t: (min, max) ranges."""
    axis = rng.uniform(-1, 1, 3)
    rvec = rng.uniform(*theta) * np.sign(rng.uniform(-1, 1)) * axis
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(rvec)[0]
    T[:3, 3] = rng.uniform(*t, 3) * np.sign(rng.uniform(-1, 1, 3))
    return T


def perturb(rng, T, sigma_r, sigma_t):
    """OpenCV's noise: Gaussian on the rotation vector and on the translation."""
    out = T.copy()
    out[:3, :3] = cv2.Rodrigues(cv2.Rodrigues(T[:3, :3])[0].ravel() + rng.normal(0, sigma_r, 3))[0]
    out[:3, 3] += rng.normal(0, sigma_t, 3)
    return out


def simulate_opencv(rng, n_poses=10, noise=True):
    """One trial of OpenCV's ``simulateData``: (gripper2base (n, 4, 4), target2cam (n, 4, 4), X (4, 4))."""
    deg = math.pi / 180
    X = generate_pose(rng, (10 * deg, 50 * deg), (0.05, 0.5))
    target2base = generate_pose(rng, (5 * deg, 85 * deg), (0.5, 3.5))
    g2b, t2c = [], []
    for _ in range(n_poses):
        G = generate_pose(rng, (5 * deg, 45 * deg), (0.5, 1.5))
        C = np.linalg.inv(X) @ np.linalg.inv(G) @ target2base
        if noise:
            C, G = perturb(rng, C, 0.002, 0.005), perturb(rng, G, 0.001, 0.001)
        g2b.append(G)
        t2c.append(C)
    return np.stack(g2b), np.stack(t2c), X
