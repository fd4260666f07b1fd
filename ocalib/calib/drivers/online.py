"""The streaming calibration head: rig extrinsics from every camera's pose, every frame, in O(1).

Convention: input poses are camera-to-world (..., C, 4, 4), one world frame per camera (each camera's
trajectory may live in its own world and units: only motions are used). Camera 0 is the reference;
the output is ``T_cam0_camk`` for k = 1..C-1 and the scale of camera k's units into camera 0's.
"""

from __future__ import annotations

import copy
import importlib.util
import math

import torch
from torch import Tensor, nn

from ocalib.calib.drivers.result import Calibration
from ocalib.calib.stages.gating import Gates, check_poses, rig_poses, rotation_weights, screw_gate
from ocalib.calib.stages.handeye import (
    STATISTICS,
    TranslationMoment,
    rotation_blocks,
    translation_quadratic,
    translation_rows,
    update_translation_moment,
)
from ocalib.calib.stages.pairing import MOTIONS, combine_statistics, motions_since
from ocalib.calib.stages.refine import REFINE_MODES, refine_estimate
from ocalib.calib.stages.rotation import RotationSystem, rotation_gram, update_rotation_system
from ocalib.calib.stages.solve import closed_form
from ocalib.calib.stages.translation import SCALE_FITS, fit_scale, rls_update
from ocalib.errors import deferred_interrupts

HAVE_NUMBA = importlib.util.find_spec("numba") is not None  # the compiled CPU kernel's compiler


class OnlineCalibrator(nn.Module):
    """On-line hand-eye calibration of B rigs of C cameras (camera 0 against cameras 1..C-1).

    A frame runs the head's stages, each a pure function of its module: the pose checks
    (:func:`~ocalib.calib.stages.gating.check_poses`); the motions of every camera over a set of frame gaps (``motion``,
    :func:`~ocalib.calib.stages.pairing.motions_since`); the screw-congruence gate and the rotation rows' weights
    (:mod:`ocalib.calib.stages.gating`); each gap's rotation system by incremental SVD
    (:func:`~ocalib.calib.stages.rotation.update_rotation_system`) and its translation moment by a sum
    (:func:`~ocalib.calib.stages.handeye.update_translation_moment`); the gaps combined with weights from their noise
    (:func:`~ocalib.calib.stages.pairing.combine_statistics`); the closed form
    (:func:`~ocalib.calib.stages.solve.closed_form`: translation and scale by the exact moment solver) or the paper's
    RLS (:mod:`ocalib.calib.stages.translation`); and the joint refinement of rotation, translation and scale
    (:func:`~ocalib.calib.stages.refine.refine_estimate`); last the scale fit
    (:func:`~ocalib.calib.stages.translation.fit_scale`). All state is kept in buffers, so ``state_dict`` saves and
    restores a stream mid-way; gradients flow to the poses.

    Args:
        num_cameras: C, cameras per rig, camera 0 the reference.
        batch_size: B, rigs calibrated at once.
        motion: ``first``, ``consecutive`` or ``multi`` (see :data:`MOTIONS`), or a tuple of gaps
            (0 stands for the pair with frame 0).
        solver: ``exact`` (moment solver, equals batch least squares) or ``rls`` (the paper's).
        refine: with the exact solver, refine the closed form jointly every frame (equals the batch joint
            least squares of :func:`~ocalib.calib.drivers.batch.batch_calibrate`); False: the closed form (rotation
            first, then translation and scale), which equals the batch closed form; ``"unobservable"``: refine
            only where the rotation rows alone leave the rotation unobservable (monocular front ends, whose
            translation directions are biased: see :data:`~ocalib.calib.stages.refine.REFINE_MODES`).
        scale_fit: how the exact solver fits the scale (the RLS keeps its own): ``"symmetric"`` with no preferred
            camera, the geometric mean of regressing each camera's translations on the other's
            (:func:`~ocalib.calib.stages.translation.symmetric_scale`); ``"regression"``: least squares' regression of
            camera 0's translations on camera k's, biased toward 0 by camera k's translation noise however many
            frames come.
        symmetric: translation rows of every motion pair in both directions (see :mod:`ocalib.calib.stages.handeye`).
        forgetting: ``lam`` in (0, 1]; old rows weigh ``lam`` per frame.
        rls_c0, rls_delay: the RLS's initial covariance ``C0 = c0 I`` and the frame it starts at.
        gates: the thresholds of the pose checks, the screw gate and the robust weights
            (:class:`~ocalib.calib.stages.gating.Gates`; :data:`~ocalib.calib.stages.gating.NO_GATES` keeps only the
            pose checks).
        backend: ``"auto"`` runs a frame in the compiled CPU kernel (:mod:`ocalib.calib.drivers.kernel`, the stages'
            compiled twins: PyTorch's dispatch of small operations is what a frame costs there) where it applies --
            CPU, float64, ``solver="exact"``, no gradients -- and in PyTorch elsewhere; ``"torch"`` always in
            PyTorch.
    """

    def __init__(
        self,
        num_cameras: int = 2,
        batch_size: int = 1,
        motion: str | tuple[int, ...] = "multi",
        solver: str = "exact",
        refine: bool | str = True,
        scale_fit: str = "symmetric",
        symmetric: bool = True,
        forgetting: float = 1.0,
        rls_c0: float = 1e4,
        rls_delay: int = 0,
        gates: Gates = Gates(),  # noqa: B008 (frozen)
        backend: str = "auto",
        dtype: torch.dtype = torch.float64,
        device: torch.device | str | None = None,
    ):
        super().__init__()
        if num_cameras < 2:
            raise ValueError(f"a rig needs at least 2 cameras, got num_cameras={num_cameras}")
        if solver not in ("exact", "rls"):
            raise ValueError(f"solver must be 'exact' or 'rls', got {solver!r}")
        if not 0 < forgetting <= 1:
            raise ValueError(f"forgetting must be in (0, 1], got {forgetting}")
        if refine not in REFINE_MODES:
            raise ValueError(f"refine must be one of {REFINE_MODES}, got {refine!r}")
        if scale_fit not in SCALE_FITS:
            raise ValueError(f"scale_fit must be one of {SCALE_FITS}, got {scale_fit!r}")
        if backend not in ("auto", "torch"):
            raise ValueError(f"backend must be 'auto' or 'torch', got {backend!r}")
        gaps = MOTIONS[motion] if isinstance(motion, str) else tuple(int(g) for g in motion)
        if not gaps or min(gaps) < 0:
            raise ValueError(f"motion gaps must be non-negative frame counts, got {gaps}")
        self.num_cameras, self.batch_size, self.gaps, self.solver = num_cameras, batch_size, gaps, solver
        self.refine, self.symmetric = refine if solver == "exact" else False, symmetric
        self.scale_fit = scale_fit if solver == "exact" else "regression"  # the RLS fits its own
        self.forgetting, self.rls_c0, self.rls_delay = forgetting, rls_c0, rls_delay
        self.min_rotation = math.radians(gates.min_rotation_deg)
        self.screw_gate, self.screw_gate_sigma = math.radians(gates.screw_gate_deg), gates.screw_gate_sigma
        self.robust = math.radians(gates.robust_deg)
        self.pose_tolerance = gates.pose_tolerance
        self.history_size = max(max(gaps), 1)
        self.backend = backend
        self._dtype, self._device = dtype, device
        self.reset()

    def reset(self) -> None:
        """Forget everything: the next frame is frame 0."""
        B, C, K, P = self.batch_size, self.num_cameras, self.num_cameras - 1, len(self.gaps)
        f = dict(dtype=self._dtype, device=self._device)
        eye4 = torch.eye(4, **f)
        state = {
            "frame": torch.zeros((), dtype=torch.long, device=self._device),
            "gap_tensor": torch.tensor([g for g in self.gaps if g > 0], dtype=torch.long, device=self._device),
            "history": eye4.expand(B, C, self.history_size, 4, 4).clone(),
            "history_valid": torch.zeros(B, C, self.history_size, dtype=torch.bool, device=self._device),
            "first": eye4.expand(B, C, 4, 4).clone(),
            "first_valid": torch.zeros(B, dtype=torch.bool, device=self._device),
            # per gap (in the order of the motion pairs: positive gaps, then gap 0)
            "gap_S2": torch.zeros(B, K, P, 4, **f),
            "gap_V": eye4.expand(B, K, P, 4, 4).clone(),
            "gap_rotation_rows": torch.zeros(B, K, P, **f),
            "gap_Z": torch.zeros(B, K, P, STATISTICS, **f),
            "gap_translation_rows": torch.zeros(B, K, P, **f),
            "gap_Z_reverse": torch.zeros(B, K, P, STATISTICS, **f),
            # the combined rotation system of the last frame (its estimate weighs the next frame's rows)
            "S2": torch.zeros(B, K, 4, **f),
            "V": eye4.expand(B, K, 4, 4).clone(),
            "rotation_rows": torch.zeros(B, K, **f),
            "rls_x": torch.zeros(B, K, 4, **f),
            "rls_C": self.rls_c0 * eye4.expand(B, K, 4, 4).clone(),
            "screw_scale": torch.zeros(B, K, **f),
            "screw_count": torch.zeros(B, K, **f),
            "frames_used": torch.zeros(B, K, dtype=torch.long, device=self._device),
            "frames_rejected": torch.zeros(B, K, dtype=torch.long, device=self._device),
        }
        for name, value in state.items():
            self.register_buffer(name, value)

    def forward(self, poses: Tensor) -> Calibration:
        """Consume one synchronised frame. poses: (B, C, 4, 4) or (C, 4, 4) camera-to-world."""
        poses = rig_poses(poses, self.batch_size, self.num_cameras)
        st = self._buffers  # the state, read and replaced directly (nn.Module attribute access is slow)
        differentiable = torch.is_grad_enabled() and (poses.requires_grad or st["gap_Z"].requires_grad)
        if self._kernel_applies(poses, differentiable):
            from ocalib.calib.drivers import kernel  # numba loads on first use (~0.3 s): not for every import of ocalib

            return Calibration(**kernel.step(self, poses))
        poses, valid = check_poses(poses.to(st["S2"].dtype), self.pose_tolerance)
        pairs = motions_since(*self._earlier(poses, valid, differentiable), poses, valid)
        ok, st["screw_scale"], st["screw_count"] = screw_gate(
            pairs.angle, pairs.valid, st["screw_scale"], st["screw_count"], self.screw_gate, self.screw_gate_sigma
        )
        A = rotation_blocks(pairs.quaternion)  # (B, K, P, 4, 4)
        weight = rotation_weights(ok, pairs.angle, A, self._get("", RotationSystem), self.min_rotation, self.robust)
        gaps = update_rotation_system(self._get("gap_", RotationSystem), A, weight, self.forgetting)
        gap_moments = update_translation_moment(
            self._get("gap_", TranslationMoment), pairs.motion, ok, self.forgetting, self.symmetric
        )
        rotation, moment, gap_weights = combine_statistics(
            rotation_gram(gaps.S2, gaps.V), gaps.S2, gaps.rotation_rows, gap_moments
        )
        quadratic = translation_quadratic(moment.Z)
        est = closed_form(rotation, quadratic)
        reverse = translation_quadratic(moment.Z_reverse)  # zero (and weighing nothing) with rows one way
        est = refine_estimate(est, rotation, quadratic, moment.translation_rows, self.refine, reverse=reverse)
        est = fit_scale(est, quadratic, self.scale_fit)
        self._set("gap_", gaps, gap_moments)
        self._set("", rotation)
        if self.solver == "rls":
            est.update(self._rls(pairs.motion, est, ok * gap_weights))
        used = ok.any(-1)
        st["frames_used"] = st["frames_used"] + used
        st["frames_rejected"] = st["frames_rejected"] + (~used & (st["frame"] > 0))
        st["frame"] = st["frame"] + 1
        return Calibration.from_statistics(est, rotation, moment, st["frames_used"], st["frames_rejected"])

    def _get(self, prefix: str, kind: type):
        """The buffers ``prefix + field`` of the named tuple ``kind``, as one."""
        return kind(*(self._buffers[prefix + name] for name in kind._fields))

    def _set(self, prefix: str, *groups) -> None:
        """Replace the buffers ``prefix + field`` by the fields of the named tuples ``groups``, contiguous (a
        solver's output may be laid out otherwise, e.g. ``eigh``'s eigenvectors: a compiled head would recompile)."""
        for group in groups:
            self._buffers.update(zip((prefix + name for name in group._fields), (v.contiguous() for v in group)))

    def _earlier(self, poses: Tensor, valid: Tensor, differentiable: bool) -> tuple[Tensor, Tensor]:
        """The start poses (B, C, P, 4, 4) of this frame's motion pairs (gap g: frame t - g; gap 0: the first frame
        with every pose valid, from the frame after it) and which are valid (B, C, P); this frame joins the history."""
        st = self._buffers
        slots = (st["frame"] - st["gap_tensor"]) % self.history_size
        earlier, earlier_valid = [st["history"].index_select(2, slots)], [st["history_valid"].index_select(2, slots)]
        if 0 in self.gaps:
            earlier.append(st["first"].unsqueeze(2))
            earlier_valid.append(st["first_valid"][:, None, None].expand(-1, self.num_cameras, 1))
            start = valid.all(-1) & ~st["first_valid"]
            st["first"] = torch.where(start[:, None, None, None], poses, st["first"])
            st["first_valid"] = st["first_valid"] | start
        slot = (st["frame"] % self.history_size).reshape(1)
        if differentiable:  # keep earlier frames' graph intact
            st["history"] = st["history"].index_copy(2, slot, poses.unsqueeze(2))
        else:  # in place: the ring buffer is the largest state (B x C x 32 poses)
            st["history"] = st["history"].detach().index_copy_(2, slot, poses.unsqueeze(2))
        st["history_valid"] = st["history_valid"].index_copy(2, slot, valid.unsqueeze(2))
        return torch.cat(earlier, 2), torch.cat(earlier_valid, 2)

    def _rls(self, motion: Tensor, est: dict[str, Tensor], weight: Tensor) -> dict[str, Tensor]:
        """The paper's recursive least squares: translation (B, K, 3) and scale (B, K) from the translation rows of
        camera 0's motions against camera k's (``motion`` (B, C, P, 4, 4)) with the rotation of ``est``, each pair
        weighing ``weight`` (B, K, P)."""
        st = self._buffers
        R0, t0, t1 = motion[:, :1, :, :3, :3], motion[:, :1, :, :3, 3], motion[:, 1:, :, :3, 3]
        B, b = translation_rows(
            R0.expand(-1, t1.shape[1], -1, -1, -1), t0.expand_as(t1), t1, est["rotation"][:, :, None]
        )
        sw = weight.sqrt()[..., None]
        x, C = rls_update(st["rls_x"], st["rls_C"], (sw[..., None] * B).flatten(-3, -2), (sw * b).flatten(-2),
                          self.forgetting)  # fmt: skip
        go = st["frame"] >= self.rls_delay
        x = st["rls_x"] = torch.where(go, x, st["rls_x"])
        st["rls_C"] = torch.where(go, C, st["rls_C"])
        axis = est["planar_axis"]
        return {"translation": x[..., :3] - axis * (axis * x[..., :3]).sum(-1, keepdim=True), "scale": x[..., 3]}

    def load_kernel(self) -> None:
        """Compile the CPU kernel this head's frames run in, or load it from numba's cache, by running a copy of the
        head on one frame of identity poses; a no-op where the kernel does not apply. A stream calls it before it
        starts, so that no frame waits for the compiler (a minute on a first run) while the stream's workers run. Ctrl-C
        takes effect once the compiler is done (numba's state breaks where an interrupt lands inside it)."""
        device = self._buffers["S2"].device
        poses = torch.eye(4, dtype=torch.float64, device=device).expand(self.batch_size, self.num_cameras, 4, 4)
        if self._kernel_applies(poses, differentiable=False):
            with deferred_interrupts():
                copy.deepcopy(self)(poses)

    def _kernel_applies(self, poses: Tensor, differentiable: bool) -> bool:
        """Whether this frame runs in the compiled CPU kernel (see ``backend``)."""
        return (self.backend == "auto" and self.solver == "exact" and not differentiable and HAVE_NUMBA
                and poses.device.type == "cpu" and self._buffers["S2"].dtype == torch.float64
                and self._buffers["S2"].device.type == "cpu" and not torch.compiler.is_compiling())  # fmt: skip
