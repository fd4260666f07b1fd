"""The streaming head's frame update as a compiled CPU kernel (numba): the same stages, without PyTorch's
per-operation dispatch.

:class:`~ocalib.calib.drivers.online.OnlineCalibrator` spends its CPU time dispatching about 900 small tensor operations
a frame (about 2 us each), not computing. This driver runs one frame of the head for every rig by chaining the
compiled twins of its stages, each in the ``*_kernel`` module beside its PyTorch stage and tested against it:

=======================  =====================================  ============================================
stage                    PyTorch, in ocalib.calib.stages        compiled twin
=======================  =====================================  ============================================
pose checks              ``gating.check_poses``                 ``gating_kernel.check_poses``
motion pairs             ``pairing.motions_since``              ``pairing_kernel.motions_since``
screw gate               ``gating.screw_gate``                  ``gating_kernel.screw_gate``
rotation rows' weights   ``gating.rotation_weights``            ``gating_kernel.rotation_weights``
per-gap rotation system  ``rotation.update_rotation_system``    ``rotation_kernel.update_rotation_system``
per-gap moment           ``handeye.update_translation_moment``  ``handeye_kernel.update_translation_moment``
gap combination          ``pairing.combine_statistics``         ``pairing_kernel.combine_statistics``
closed form              ``solve.closed_form``                  ``solve_kernel.closed_form``
refinement               ``refine.refine_estimate``             ``refine_kernel.refine_estimate``
scale fit                ``translation.fit_scale``              ``translation_kernel.fit_scale``
=======================  =====================================  ============================================

The twins work on one rig (and camera k) in float64, updating the head's buffers in place (``state_dict`` is
unchanged); the statistics travel in the same named tuples as in PyTorch
(:class:`~ocalib.calib.stages.rotation.RotationSystem`, :class:`~ocalib.calib.stages.handeye.TranslationMoment`,
:class:`~ocalib.calib.stages.pairing.MotionPairs`). From ``PARALLEL_MIN_RIGS`` rigs up, rigs run in parallel over
numba's threads. The tests hold the kernel equal to the PyTorch head frame by frame. Eigenvectors may differ from
LAPACK's (see :mod:`ocalib.calib.stages.linalg_kernel`): everything the head reports is invariant to that except the
null vector of an unobservable rotation and the sign of the planar axis. Where a system is rank-deficient (the planar
route on fewer than 3 motion pairs), rounding can decide which eigenvalues the pseudo-inverse cuts, and the two
minimum-norm solutions differ.

Scope: CPU, float64, ``solver="exact"``, no gradients. Everything else runs the PyTorch head.

Convention: as :mod:`ocalib.calib.drivers.online`: poses camera-to-world, ``T_cam0_camk``, quaternions (w, x, y, z).
"""

from __future__ import annotations

from collections import namedtuple
from typing import NamedTuple

import numba
import numpy as np
import torch
from numba import prange
from torch import Tensor

from ocalib.calib.stages import (
    gating_kernel,
    handeye_kernel,
    pairing_kernel,
    refine_kernel,
    rotation_kernel,
    solve_kernel,
    translation_kernel,
)
from ocalib.calib.stages.handeye import STATISTICS, TranslationMoment
from ocalib.calib.stages.linalg_kernel import compiled, jit, jit_inline
from ocalib.calib.stages.pairing import MotionPairs
from ocalib.calib.stages.refine import REFINE_STEPS
from ocalib.calib.stages.rotation import RotationSystem

PARALLEL_MIN_RIGS = 16  # fewer rigs run on the calling thread (starting the thread pool costs more)


class State(NamedTuple):
    """The head's buffers the kernel reads and updates (numpy views of them)."""

    history: np.ndarray
    history_valid: np.ndarray
    first: np.ndarray
    first_valid: np.ndarray
    gap_S2: np.ndarray
    gap_V: np.ndarray
    gap_rotation_rows: np.ndarray
    gap_Z: np.ndarray
    gap_translation_rows: np.ndarray
    gap_Z_reverse: np.ndarray
    S2: np.ndarray
    V: np.ndarray
    rotation_rows: np.ndarray
    screw_scale: np.ndarray
    screw_count: np.ndarray
    frames_used: np.ndarray
    frames_rejected: np.ndarray


class Settings(NamedTuple):
    """The head's settings and the frame number."""

    gaps: np.ndarray  # the positive gaps (the pair with the first frame comes after them)
    has_first: bool  # whether there is a pair with the first frame
    frame: int
    symmetric: bool
    forgetting: float
    min_rotation: float
    screw_gate: float
    screw_gate_sigma: float
    robust: float
    pose_tolerance: float
    refine: int  # refine_kernel.REFINE_CODES
    refine_steps: int
    scale_fit: int  # translation_kernel.SCALE_FIT_CODES


# The estimate's arrays (B, K, *shape): the fields of :class:`~ocalib.calib.drivers.result.Calibration`.
OUTPUTS = {"rotation": ((3, 3), np.float64), "quaternion": ((4,), np.float64), "translation": ((3,), np.float64),
           "scale": ((), np.float64), "rotation_singular_values": ((4,), np.float64),
           "rotation_observable": ((), np.bool_), "planar_motion": ((), np.bool_), "planar_axis": ((3,), np.float64),
           "frames_used": ((), np.int64), "frames_rejected": ((), np.int64), "rotation_basis": ((4, 4), np.float64),
           "rotation_rows": ((), np.float64), "translation_moment": ((STATISTICS,), np.float64),
           "translation_rows": ((), np.float64), "refined": ((), np.bool_),
           "translation_moment_reverse": ((STATISTICS,), np.float64)}  # fmt: skip
Outputs = namedtuple("Outputs", list(OUTPUTS))


class Workspace(NamedTuple):
    """One thread's scratch arrays: a rig's checked poses and motion pairs, one camera's pairs, the twins' own."""

    poses: np.ndarray  # (C, 4, 4)
    valid: np.ndarray  # (C,)
    earlier: np.ndarray  # (C, P, 4, 4)
    earlier_valid: np.ndarray  # (C, P)
    pairs: MotionPairs
    ok: np.ndarray  # (K, P)
    A: np.ndarray  # (P, 4, 4)
    weight: np.ndarray  # (P,)
    z: np.ndarray  # (2, 15)
    x: np.ndarray  # (4,) translation and scale
    P: np.ndarray  # (12, 12) the translation quadratic
    p: np.ndarray  # (12,)
    P_reverse: np.ndarray  # (12, 12) the reverse rows' share of the translation quadratic
    p_reverse: np.ndarray  # (12,)
    rotation: rotation_kernel.Workspace
    combine: pairing_kernel.Workspace
    solve: solve_kernel.Workspace
    refine: refine_kernel.Workspace


@jit
def _workspace(C, n_pairs):
    return Workspace(np.empty((C, 4, 4)), np.empty(C, dtype=np.bool_), np.empty((C, n_pairs, 4, 4)),
                     np.empty((C, n_pairs), dtype=np.bool_),
                     MotionPairs(np.empty((C, n_pairs, 4, 4)), np.empty((C, n_pairs, 4)), np.empty((C, n_pairs)),
                                 np.empty((C - 1, n_pairs), dtype=np.bool_)),
                     np.empty((C - 1, n_pairs), dtype=np.bool_), np.empty((n_pairs, 4, 4)), np.empty(n_pairs),
                     np.empty((2, 15)), np.empty(4), np.empty((12, 12)), np.empty(12), np.empty((12, 12)),
                     np.empty(12), rotation_kernel.workspace(), pairing_kernel.workspace(n_pairs),
                     solve_kernel.workspace(), refine_kernel.workspace())  # fmt: skip


@jit_inline
def _rig_step(b, poses, state, settings, out, work):
    """One frame of rig ``b``: its ``poses`` (C, 4, 4); ``state`` updated, ``out[b]`` written."""
    gating_kernel.check_poses(poses, settings.pose_tolerance, work.poses, work.valid)
    _earlier(b, state, settings, work)
    pairing_kernel.motions_since(work.earlier, work.earlier_valid, work.poses, work.valid, work.pairs)
    gating_kernel.screw_gate(work.pairs.angle, work.pairs.valid, state.screw_scale[b], state.screw_count[b],
                             settings.screw_gate, settings.screw_gate_sigma, work.ok)  # fmt: skip
    for k in range(work.ok.shape[0]):
        _camera_step(b, k, state, settings, out, work)


@jit_inline
def _camera_step(b, k, state, settings, out, work):
    """Camera k + 1 of rig ``b``, from the rig's gated motion pairs in ``work``."""
    pairs, ok, A, weight = work.pairs, work.ok[k], work.A, work.weight
    handeye_kernel.rotation_blocks(pairs.quaternion[0], pairs.quaternion[k + 1], A)
    last = RotationSystem(state.S2[b, k], state.V[b, k], state.rotation_rows[b, k])  # the last frame's estimate
    gating_kernel.rotation_weights(ok, pairs.angle[0], pairs.angle[k + 1], A, last, settings.min_rotation,
                                   settings.robust, weight)  # fmt: skip
    gaps = RotationSystem(state.gap_S2[b, k], state.gap_V[b, k], state.gap_rotation_rows[b, k])
    rotation_kernel.update_rotation_system(gaps, A, weight, settings.forgetting, work.rotation)
    gap_moment = TranslationMoment(state.gap_Z[b, k], state.gap_translation_rows[b, k], state.gap_Z_reverse[b, k])
    handeye_kernel.update_translation_moment(gap_moment, pairs.motion[0], pairs.motion[k + 1], ok, settings.forgetting,
                                             settings.symmetric, work.z)  # fmt: skip
    Z, Z_reverse = out.translation_moment[b, k], out.translation_moment_reverse[b, k]
    rows, translation_rows = pairing_kernel.combine_statistics(gaps, gap_moment, state.S2[b, k], state.V[b, k], Z,
                                                               Z_reverse, work.combine)  # fmt: skip
    state.rotation_rows[b, k] = rows
    rotation = RotationSystem(state.S2[b, k], state.V[b, k], rows)
    quadratic = (work.P, work.p, handeye_kernel.translation_quadratic(Z, work.P, work.p))
    est = solve_kernel.Estimate(out.quaternion[b, k], out.rotation[b, k], work.x, out.rotation_singular_values[b, k],
                                out.planar_axis[b, k])  # fmt: skip
    flags = solve_kernel.closed_form(rotation, quadratic, est, work.solve)
    c_reverse = handeye_kernel.translation_quadratic(Z_reverse, work.P_reverse, work.p_reverse)
    reverse = (work.P_reverse, work.p_reverse, c_reverse)
    out.refined[b, k] = refine_kernel.refine_estimate(est, rotation, quadratic, reverse, translation_rows,
                                                      settings.refine, settings.refine_steps, flags,
                                                      work.refine)  # fmt: skip
    translation_kernel.fit_scale(est, quadratic, settings.scale_fit, work.solve.solve)
    out.rotation_observable[b, k], out.planar_motion[b, k] = flags
    out.translation[b, k], out.scale[b, k] = work.x[:3], work.x[3]
    used = False
    for j in range(ok.shape[0]):
        used = used or ok[j]
    state.frames_used[b, k] += 1 if used else 0
    state.frames_rejected[b, k] += 1 if (not used and settings.frame > 0) else 0
    out.frames_used[b, k], out.frames_rejected[b, k] = state.frames_used[b, k], state.frames_rejected[b, k]
    out.rotation_basis[b, k] = state.V[b, k]
    out.rotation_rows[b, k], out.translation_rows[b, k] = rows, translation_rows


@jit_inline
def _earlier(b, state, settings, work):
    """The start poses of rig ``b``'s motion pairs and their validity (``work.earlier``, ``work.earlier_valid``); its
    checked poses (``work.poses``) join the history (and, the first time all are valid, become the first frame)."""
    C, H, n_gaps = work.poses.shape[0], state.history.shape[2], settings.gaps.shape[0]
    for cam in range(C):
        for j in range(n_gaps):
            slot = (settings.frame - settings.gaps[j]) % H
            _copy_pose(state.history[b, cam, slot], work.earlier[cam, j])
            work.earlier_valid[cam, j] = state.history_valid[b, cam, slot]
        if settings.has_first:
            _copy_pose(state.first[b, cam], work.earlier[cam, n_gaps])
            work.earlier_valid[cam, n_gaps] = state.first_valid[b]
    start = settings.has_first and not state.first_valid[b]
    for cam in range(C):
        _copy_pose(work.poses[cam], state.history[b, cam, settings.frame % H])
        state.history_valid[b, cam, settings.frame % H] = work.valid[cam]
        start = start and work.valid[cam]
    if start:
        for cam in range(C):
            _copy_pose(work.poses[cam], state.first[b, cam])
        state.first_valid[b] = True


@jit
def _copy_pose(src, dst):
    """``dst[:, :] = src`` for 4x4 arrays, in loops (numba's slice assignment costs twice as much)."""
    for i in range(4):
        for j in range(4):
            dst[i, j] = src[i, j]


@jit
def _rigs(poses, state, settings, out, start, stop):
    """Frames of rigs ``start`` to ``stop`` (``state``, ``settings``, ``out``: the plain tuples ``step`` passes)."""
    state, settings, out = State(*state), Settings(*settings), Outputs(*out)
    work = _workspace(poses.shape[1], settings.gaps.shape[0] + settings.has_first)
    for b in range(start, stop):
        _rig_step(b, poses[b], state, settings, out, work)


@compiled(parallel=True)
def _parallel(poses, state, settings, out, chunks):
    """:func:`_rigs` of all rigs, in ``chunks`` over numba's threads."""
    for chunk in prange(chunks):
        _rigs(poses, state, settings, out, chunk * len(poses) // chunks, (chunk + 1) * len(poses) // chunks)


def step(head, poses: Tensor) -> dict[str, Tensor]:
    """Run one frame of ``head`` (an :class:`~ocalib.calib.drivers.online.OnlineCalibrator` with ``solver="exact"``,
    float64 buffers on the CPU) on ``poses`` (B, C, 4, 4), updating its buffers in place. Returns the fields of
    :class:`~ocalib.calib.drivers.result.Calibration`, in new arrays every frame (as fast as reusing the last frame's:
    the allocator hands their memory back once the caller drops them; 0.5 us an array)."""
    B, K = head.batch_size, head.num_cameras - 1
    buffers, state = _numpy_buffers(head)
    settings = (buffers["gap_tensor"], 0 in head.gaps, int(buffers["frame"]), head.symmetric, float(head.forgetting),
                head.min_rotation, head.screw_gate, head.screw_gate_sigma, head.robust, head.pose_tolerance,
                refine_kernel.REFINE_CODES[head.refine], REFINE_STEPS,
                translation_kernel.SCALE_FIT_CODES[head.scale_fit])  # fmt: skip
    out = tuple(np.empty((B, K) + shape, dtype) for shape, dtype in OUTPUTS.values())
    args = (poses.detach().to(torch.float64).contiguous().numpy(), state, settings, out)
    threads = numba.get_num_threads()
    if B >= PARALLEL_MIN_RIGS and threads > 1:
        _parallel(*args, min(B, 8 * threads))
    else:
        _rigs(*args, 0, B)
    buffers["frame"] += 1
    return {name: torch.from_numpy(value) for name, value in zip(OUTPUTS, out)}


def _numpy_buffers(head) -> tuple[dict[str, np.ndarray], tuple[np.ndarray, ...]]:
    """Numpy views of ``head``'s buffers, by name and (the kernel's state) in the order of :class:`State`, kept while
    every buffer's memory is where it was (``Tensor.numpy`` costs 2-4 us: all of them, a third of a frame of one rig).
    The views hold their tensors, so a buffer the module replaced cannot come back at a kept address."""
    addresses = list(map(Tensor.data_ptr, head._buffers.values()))
    kept = head.__dict__.get("_kernel_buffers")
    if kept is None or kept[0] != addresses:
        arrays = {name: t.numpy() for name, t in head._buffers.items()}
        kept = head.__dict__["_kernel_buffers"] = (addresses, arrays, tuple(arrays[name] for name in State._fields))
    return kept[1], kept[2]
