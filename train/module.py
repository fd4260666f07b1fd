"""The LightningModule: self-supervised depth and ego-motion from snippets (monodepth2 + SC-SfMLearner losses).

Convention: batches as :mod:`ocalib.data.snippets` (``image`` (B, S, 3, H, W) target first, ``K`` (B, 3, 3),
``poses`` (B, S, 4, 4) = pose of frame s in the target's frame, ``depth`` (B, S, 1, H, W) metres, when known).
The pose net predicts ``T_target_source``; the warp uses its inverse.
"""

from __future__ import annotations

import math
import os
import shutil
from collections import defaultdict

import lightning.pytorch as pl
import numpy as np
import torch
from lightning.pytorch.callbacks import Timer
from lightning.pytorch.utilities import rank_zero_warn
from ocalib.train.visuals import colorize, trajectory_figure
from torch import Tensor

from ocalib.errors import InputError
from ocalib.eval.depth_metrics import depth_errors
from ocalib.eval.pose_metrics import motion_errors, rotation_gain
from ocalib.frontend.align import align_motion
from ocalib.geometry.pose import invert_pose
from ocalib.geometry.se3 import chain_motions
from ocalib.losses import LossOutput, SelfSupervisedLoss
from ocalib.losses.motion import motion_distance
from ocalib.losses.selfsup import identity_errors, self_supervised_loss
from ocalib.models import MAX_DEPTH, EgoMotionModel, disp_to_depth, load_model

MIN_TRANSLATION = 1e-3  # true motions shorter than this have no translation direction or scale ratio


class EgoMotionModule(pl.LightningModule):
    """Trains an :class:`~ocalib.models.EgoMotionModel` (``size``, ``height``, ``width``).

    Loss: ``automask``, ``smoothness``, ``geometry`` (0 disables SC-SfMLearner's consistency loss and mask)
    as :class:`~ocalib.losses.SelfSupervisedLoss`, over the first ``scales`` disparity scales. Adam with
    ``lr``, ``weight_decay``, linear warm-up over ``warmup_steps`` then cosine decay to ``min_lr_ratio x lr``
    at the last step, or at the trainer's ``max_time`` if that comes first (:func:`lr_factor`). ``align``:
    Gauss-Newton steps per pyramid level, coarsest first (:func:`~ocalib.frontend.align.align_motion`, no rotation
    limit; empty: off): in training, the depth network learns from the pose network's motions refined on its own
    depth, and the pose network from its own motions with the depth detached, so that the depth does not absorb the
    pose network's errors. The network's depth scale is free and is held by the loss's scale gauge;
    ``train/depth_median`` and ``train/depth_far_share`` (the share of pixels beyond half of the depth range's far
    end) show it in TensorBoard. ``distill``: weight of the pose network's distance to the refined motions
    (:func:`~ocalib.losses.motion.motion_distance`, degrees + relative translation; 0: off; with ``align`` only).
    Images go to TensorBoard every ``image_interval`` steps; ``trajectory_frames``: length of the validation
    trajectory plotted. ``compile``: the training step (networks, alignment and loss, forward and backward) runs
    through ``torch.compile`` (inductor), compiled on the first step (:meth:`compiled_step`; eager, with a
    warning, on a CPU without a C++ compiler); validation stays eager. ``init_from``: start from the weights of an
    ocalib model file or training ``.ckpt`` (``"default"``: the shipped model) to fine-tune it on new sequences; its
    ``size`` must be this module's.
    """

    def __init__(
        self,
        size: str = "small",
        height: int = 64,
        width: int = 208,
        lr: float = 3e-4,
        weight_decay: float = 0.0,
        warmup_steps: int = 200,
        min_lr_ratio: float = 0.05,
        automask: bool = True,
        smoothness: float = 1e-3,
        geometry: float = 0.1,
        scales: int = 4,
        align: tuple[int, ...] = (),
        distill: float = 0.0,
        image_interval: int = 250,
        trajectory_frames: int = 200,
        compile: bool = False,
        init_from: str | None = None,
    ):
        super().__init__()
        if distill < 0 or (distill > 0 and not align):
            raise InputError(
                f"model.distill={distill}: needs to be >= 0, and > 0 only with model.align (it pulls the "
                "pose network towards the aligned motions)"
            )
        self.save_hyperparameters()
        start = None if init_from is None else load_model(None if init_from == "default" else init_from)
        if start is not None and start.size != size:
            raise InputError(f"model.init_from={init_from}: a {start.size!r} model; set model.size: {start.size}")
        self.model = EgoMotionModel(size, height, width)
        if start is not None:
            self.model.load_state_dict(start.state_dict())
        self.loss = SelfSupervisedLoss(automask, smoothness, geometry)
        self.nonfinite_steps = 0
        self._skipped = False
        self._train_step = None  # self.step, compiled on first use when hparams.compile
        self._val = defaultdict(list)

    def step(self, batch: dict) -> tuple[LossOutput, Tensor, Tensor]:
        """Loss, target disparity at full resolution (B, 1, H, W) and ``T_target_source`` (B, S-1, 4, 4)."""
        images, K = batch["image"], batch["K"]
        B, S = images.shape[:2]
        use_geometry = self.loss.geometry > 0
        disps = self.model.disparities(images.flatten(0, 1) if use_geometry else images[:, 0])
        source_depths = None
        if use_geometry:
            source_depths = disp_to_depth(disps[0].unflatten(0, (B, S))[:, 1:])
            disps = [d.unflatten(0, (B, S))[:, 0] for d in disps]
        targets = images[:, :1].expand(-1, S - 1, -1, -1, -1).flatten(0, 1)
        T = self.model.pose(targets, images[:, 1:].flatten(0, 1)).unflatten(0, (B, S - 1))
        disps = disps[: self.hparams.scales]
        if not (self.hparams.align and self.training):
            return self.loss(images, K, disps, invert_pose(T), source_depths), disps[0], T
        depth = disp_to_depth(disps[0]).repeat_interleave(S - 1, 0)
        refined, _ = align_motion(
            targets,
            images[:, 1:].flatten(0, 1),
            depth,
            K.repeat_interleave(S - 1, 0),
            invert_pose(T.detach()).flatten(0, 1),
            iterations=tuple(self.hparams.align),
            max_rotation_deg=math.inf,
        )
        identity = identity_errors(images, self.loss.ssim, self.loss.automask)  # shared by the two terms
        out = self.loss(images, K, disps, refined.unflatten(0, (B, S - 1)), source_depths, identity)
        pose = self_supervised_loss(
            images,
            K,
            [disps[0].detach()],
            invert_pose(T),
            automask=self.loss.automask,
            smoothness=0.0,
            ssim=self.loss.ssim,
            identity=identity,
        )
        out.terms["pose_photometric"] = pose.terms["photometric"]
        out.total = out.total + pose.terms["photometric"]  # not pose.total: its gauge is a constant (detached depth)
        if self.hparams.distill > 0:
            rotation, translation = motion_distance(T.flatten(0, 1), invert_pose(refined).detach())
            out.terms["pose_distill"] = rotation.mean() + translation.mean()
            out.total = out.total + self.hparams.distill * out.terms["pose_distill"]
        return out, disps[0], T

    def training_step(self, batch: dict, batch_idx: int) -> Tensor | None:
        buffers = [b.clone() for b in self.model.buffers()]  # batch-norm statistics, restored after a NaN batch
        if self._train_step is None:
            self._train_step = self.compiled_step() if self.hparams.compile else self.step
        out, disp, _ = self._train_step(batch)
        B = len(batch["image"])
        if not torch.isfinite(out.total):  # NaN guard: skip the step, count it, never crash
            with torch.no_grad():
                for b, saved in zip(self.model.buffers(), buffers):
                    b.copy_(saved)
            self.nonfinite_steps += 1
            self._skipped = True
            self.log("train/nonfinite_steps", float(self.nonfinite_steps), batch_size=B)
            # DDP: every process must run backward; the all-reduced NaN gradients are dropped on all of them below
            return out.total if self.trainer.world_size > 1 else None
        self.log("train/loss", out.total, prog_bar=True, batch_size=B)
        for name, value in out.terms.items():
            self.log(f"train/{name}", value, batch_size=B)
        with torch.no_grad():
            depth = disp_to_depth(disp.float())
            self.log("train/depth_median", depth.median(), batch_size=B)
            self.log("train/depth_far_share", (depth > 0.5 * MAX_DEPTH).float().mean(), batch_size=B)
        if self.global_step % self.hparams.image_interval == 0:
            self._log_images("train", batch, out, disp)
        return out.total

    def compiled_step(self):
        """``torch.compile(self.step)`` (what ``compile`` trains with); on the CPU without a C++ compiler (inductor
        generates C++), a warning and the eager ``self.step``."""
        compilers = (os.environ.get("CXX"), "c++", "g++", "clang++")
        if self.device.type == "cpu" and not any(c and shutil.which(c) for c in compilers):
            rank_zero_warn(
                "model.compile: torch.compile needs a C++ compiler on the CPU and none was found (CXX, c++, "
                "g++, clang++): training with the eager step (the same computation, ~1.4x slower a step)"
            )
            return self.step
        return torch.compile(self.step)

    def on_before_optimizer_step(self, optimizer) -> None:
        """NaN guard for gradients: a step with a non-finite gradient updates nothing."""
        params = [p for group in optimizer.param_groups for p in group["params"] if p.grad is not None]
        if (
            params and not torch.nn.utils.get_total_norm([p.grad for p in params]).isfinite()
        ):  # one check, not one a tensor
            for p in params:
                p.grad = None
            if not self._skipped:  # (a non-finite loss was counted already)
                self.nonfinite_steps += 1
                self.log("train/nonfinite_steps", float(self.nonfinite_steps))
        self._skipped = False

    def validation_step(self, batch: dict, batch_idx: int) -> None:
        out, disp, T = self.step(batch)
        B = len(batch["image"])
        self.log("val/loss", out.total, batch_size=B, prog_bar=True, sync_dist=True)  # DDP: the mean over processes
        for name, value in out.terms.items():
            self.log(f"val/{name}", value, batch_size=B, sync_dist=True)
        if batch_idx == 0:
            self._log_images("val", batch, out, disp)
        if "depth" in batch:
            pred = disp_to_depth(disp).detach().cpu().double().numpy()[:, 0]
            gt = batch["depth"][:, 0, 0].cpu().double().numpy()
            self._val["abs_rel"] += [e["abs_rel"] for e in map(depth_errors, pred, gt) if e is not None]
        if "poses" in batch:
            pred = T.detach().cpu().double().numpy()
            gt = batch["poses"][:, 1:].cpu().double().numpy()
            motions, truth = pred.reshape(-1, 4, 4), gt.reshape(-1, 4, 4)
            e = motion_errors(motions, truth, np.linalg.norm(truth[:, :3, 3], axis=1) > MIN_TRANSLATION)
            rot, direction, ratio = e["rotation_deg"], e["direction_deg"], e["scale_ratio"]
            self._val["rotation"] += rot.tolist()
            self._val["pred_motions"] += list(pred.reshape(-1, 4, 4))
            self._val["true_motions"] += list(gt.reshape(-1, 4, 4))
            self._val["direction"] += direction.tolist()
            S1 = pred.shape[1]
            for b in range(B):
                key = (batch["sequence"][b], batch["camera"][b])
                self._val[("ratio",) + key] += ratio[b * S1 : (b + 1) * S1].tolist()
                self._trajectory_step(key, pred[b], gt[b])

    def _trajectory_step(self, key, pred: np.ndarray, gt: np.ndarray) -> None:
        """Collect the motions to the next frame (offset +1) of the first validation camera."""
        offsets = list(getattr(getattr(self.trainer, "datamodule", None), "hparams", {}).get("offsets", (-1, 1)))
        if 1 not in offsets or self._val.setdefault("trajectory_key", key) != key:
            return
        if len(self._val["trajectory_pred"]) < self.hparams.trajectory_frames:
            self._val["trajectory_pred"].append(pred[offsets.index(1)])
            self._val["trajectory_gt"].append(gt[offsets.index(1)])

    def on_validation_epoch_end(self) -> None:
        v, self._val = self._val, defaultdict(list)
        metrics = {}
        if v["abs_rel"]:
            metrics["val/abs_rel"] = float(np.mean(v["abs_rel"]))
        if v["rotation"]:
            metrics["val/rotation_error_deg"] = float(np.median(v["rotation"]))
            metrics["val/direction_error_deg"] = float(np.nanmedian(v["direction"]))
            gains = rotation_gain(np.stack(v["pred_motions"]), np.stack(v["true_motions"]))
            metrics.update({f"val/rotation_gain_{axis}": float(g) for axis, g in zip("xyz", gains) if np.isfinite(g)})
            cvs = [np.nanstd(r) / np.nanmean(r) for k, r in v.items() if k[0] == "ratio" and np.isfinite(r).sum() > 1]
            if cvs:
                metrics["val/scale_ratio_cv"] = float(np.mean(cvs))
        if metrics:
            self.log_dict(metrics, prog_bar=False, sync_dist=True)  # DDP: each process's metrics, averaged
        if len(v["trajectory_pred"]) > 1:
            key = v["trajectory_key"]
            fig = trajectory_figure(
                chain_motions(v["trajectory_pred"]), chain_motions(v["trajectory_gt"]), f"{key[0]} / {key[1]}"
            )
            experiment = getattr(self.logger, "experiment", None)
            if hasattr(experiment, "add_figure"):
                experiment.add_figure("val/trajectory", fig, self.global_step)

    def _log_images(self, stage: str, batch: dict, out: LossOutput, disp: Tensor, n: int = 4) -> None:
        experiment = getattr(self.logger, "experiment", None)
        if not hasattr(experiment, "add_images"):
            return
        pictures = {
            "target": batch["image"][:n, 0],
            "disparity": colorize(disp[:n]),
            **{k: v[:n] for k, v in out.images.items()},
        }
        for name, picture in pictures.items():
            experiment.add_images(f"{stage}/{name}", picture.detach().float().cpu().clamp(0, 1), self.global_step)

    def configure_optimizers(self):
        h = self.hparams
        optimizer = torch.optim.Adam(self.parameters(), lr=h.lr, weight_decay=h.weight_decay, fused=True)
        total = max(1, int(self.trainer.estimated_stepping_batches))
        schedule = torch.optim.lr_scheduler.LambdaLR(
            optimizer, lambda step: lr_factor(step, total, h.warmup_steps, h.min_lr_ratio, self._time_spent())
        )
        return {"optimizer": optimizer, "lr_scheduler": {"scheduler": schedule, "interval": "step"}}

    def _time_spent(self) -> float:
        """Share of the trainer's ``max_time`` spent in training (rank 0's under DDP, so that every process steps
        with the same learning rate); 0 without a time limit. A resumed run counts the time before it too."""
        timer = next((c for c in self.trainer.callbacks if isinstance(c, Timer)), None)
        remaining = None if timer is None else timer.time_remaining()
        if remaining is None:
            return 0.0
        elapsed = timer.time_elapsed()
        return float(self.trainer.strategy.broadcast(elapsed / max(elapsed + remaining, 1e-9)))


def lr_factor(step: int, total_steps: int, warmup_steps: int, min_lr_ratio: float, time_spent: float = 0.0) -> float:
    """The learning rate's factor at ``step``: linear warm-up over ``warmup_steps``, then cosine decay to
    ``min_lr_ratio`` at the end of the run. The run's progress is the larger of the steps done (of ``total_steps``)
    and ``time_spent`` (the share of a time limit spent): a run stopped by its time limit, on a machine slower
    than the recipe's, still ends annealed instead of cut off in the middle of its schedule."""
    if step < warmup_steps:
        return (step + 1) / warmup_steps
    steps = (step - warmup_steps) / max(1, total_steps - warmup_steps)
    progress = min(1.0, max(steps, time_spent))
    return min_lr_ratio + (1 - min_lr_ratio) * 0.5 * (1 + math.cos(math.pi * progress))
