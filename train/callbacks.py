"""Callbacks of the training application: the slim model file written at the end of a fit, and a clean exit of
distributed workers."""

from __future__ import annotations

from pathlib import Path

import lightning.pytorch as pl
import torch.distributed as dist
from lightning.pytorch.trainer.states import TrainerStatus

from ocalib.models import save_model


def _plain(value):
    """A scalar, or a list of scalars (e.g. ``align``), as written into the slim model's meta; None for anything else."""
    scalar = (int, float, str, bool)
    if isinstance(value, scalar):
        return value
    if isinstance(value, (list, tuple)) and all(isinstance(v, scalar) for v in value):
        return list(value)
    return None


class ExportModel(pl.Callback):
    """On fit end, write ``<log_dir>/<filename>`` (:func:`ocalib.models.save_model`) beside the checkpoints."""

    def __init__(self, filename: str = "model.pt"):
        self.filename = filename
        self.path: Path | None = None

    def on_fit_end(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        folder = Path(trainer.log_dir or trainer.default_root_dir)  # log_dir is a collective under DDP: every rank
        if not trainer.is_global_zero:
            return
        meta = {"global_step": int(trainer.global_step), "epoch": int(trainer.current_epoch),
                "hparams": {k: p for k, v in pl_module.hparams.items() if (p := _plain(v)) is not None}}
        self.path = save_model(pl_module.model, folder / self.filename, meta)


class ReleaseProcessGroup(pl.Callback):
    """At teardown, wait for every rank (after a run that finished) and destroy the process group.

    Lightning leaves the group alive; a spawned CPU worker (``ddp_spawn``, gloo) that exits with it alive can abort
    (SIGABRT, "terminate called without an active exception") after a finished fit, failing the whole run.
    """

    def teardown(self, trainer: pl.Trainer, pl_module: pl.LightningModule, stage: str) -> None:
        if not (dist.is_available() and dist.is_initialized()):
            return
        if trainer.state.status == TrainerStatus.RUNNING:  # not after an exception: a dead rank would hang a barrier
            dist.barrier()
        dist.destroy_process_group()
