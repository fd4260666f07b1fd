"""Compiled twins (numba) of :mod:`ocalib.calib.stages.gating`: the pose checks, the screw-congruence gate and the
weights of the rotation rows, for one rig (no batch dimension; results written into the arrays passed).

Convention: as :mod:`ocalib.calib.stages.gating`; every camera's motions (C, P), the pairs of camera 0 against camera k
(K, P) or, for one camera k, (P,).
"""

from __future__ import annotations

import math

import numpy as np

from ocalib.calib.stages.gating import MAD_TO_STD, SCREW_MAX_SAMPLES, SCREW_MIN_SAMPLES
from ocalib.calib.stages.linalg_kernel import jit
from ocalib.calib.stages.rotation import ROTATION_OBSERVABLE_SIGNIFICANCE
from ocalib.calib.stages.rotation_kernel import excited, rotation_solution, singular_values


@jit
def check_poses(poses, tolerance, out, valid):
    """:func:`~ocalib.calib.stages.gating.check_poses` of a rig's poses (C, 4, 4): ``out`` (C, 4, 4) and ``valid`` (C,)
    written."""
    for cam in range(poses.shape[0]):
        pose, ok = out[cam], True
        for i in range(4):
            for j in range(4):
                pose[i, j] = poses[cam, i, j]
                ok = ok and math.isfinite(pose[i, j])
        if ok:
            err = 0.0
            for i in range(3):
                for j in range(3):
                    acc = pose[0, i] * pose[0, j] + pose[1, i] * pose[1, j] + pose[2, i] * pose[2, j]
                    err = max(err, abs(acc - (1.0 if i == j else 0.0)))
            det = ((pose[0, 1] * pose[1, 2] - pose[0, 2] * pose[1, 1]) * pose[2, 0]
                   + (pose[0, 2] * pose[1, 0] - pose[0, 0] * pose[1, 2]) * pose[2, 1]
                   + (pose[0, 0] * pose[1, 1] - pose[0, 1] * pose[1, 0]) * pose[2, 2])  # fmt: skip
            ok = max(err, abs(det - 1.0)) < tolerance
        valid[cam] = ok
        if not ok:
            for i in range(4):
                for j in range(4):
                    pose[i, j] = 1.0 if i == j else 0.0


@jit
def screw_gate(angle, valid, scale, count, gate, sigma, ok):
    """:func:`~ocalib.calib.stages.gating.screw_gate` of a rig: every camera's motion angles ``angle`` (C, P), the pairs
    ``valid`` (K, P); ``ok`` (K, P) written, the running ``scale`` and ``count`` (K,) updated in place."""
    for k in range(valid.shape[0]):
        opened = count[k] >= SCREW_MIN_SAMPLES
        thr = max(sigma * MAD_TO_STD * scale[k], gate) if opened else np.inf
        clip = 5.0 * MAD_TO_STD * scale[k] if opened else np.inf
        total, n = 0.0, 0.0
        for j in range(valid.shape[1]):
            screw = abs(angle[0, j] - angle[k + 1, j])
            ok[k, j] = valid[k, j] and screw <= thr
            if valid[k, j]:
                total += min(screw, clip)
                n += 1.0
        count[k] = min(count[k] + n, SCREW_MAX_SAMPLES)
        scale[k] += (total - n * scale[k]) / max(count[k], 1.0)


@jit
def rotation_weights(ok, angle0, anglek, A, estimate, min_rotation, robust, weight):
    """:func:`~ocalib.calib.stages.gating.rotation_weights` for one rig and camera k: the pairs ``ok`` (P,), the motion
    angles of camera 0 and camera k (P,), the blocks ``A`` (P, 4, 4), ``estimate`` a
    :class:`~ocalib.calib.stages.rotation.RotationSystem` (``S2`` (4,), ``V`` (4, 4), ``rotation_rows``); ``weight``
    (P,) written."""
    S2, V, rows = estimate
    q = rotation_solution(V)
    established = excited(singular_values(S2), rows, 2, ROTATION_OBSERVABLE_SIGNIFICANCE)
    for j in range(A.shape[0]):
        weight[j] = 1.0 if ok[j] and (angle0[j] + anglek[j]) / 2.0 >= min_rotation else 0.0
        if weight[j] > 0.0 and established:
            rr = 0.0
            for i in range(4):
                acc = A[j, i, 0] * q[0] + A[j, i, 1] * q[1] + A[j, i, 2] * q[2] + A[j, i, 3] * q[3]
                rr += acc * acc
            d = 4.0 * math.asin(min(math.sqrt(rr) / 2.0, 1.0))
            if d > robust:
                weight[j] = robust / max(d, 1e-12)
