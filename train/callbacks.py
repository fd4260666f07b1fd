"""Callbacks of the training application: the slim model file written at the end of a fit."""

from __future__ import annotations

from pathlib import Path

import lightning.pytorch as pl

from ocalib.models import save_model


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
                "hparams": {k: v for k, v in pl_module.hparams.items() if isinstance(v, (int, float, str, bool))}}
        self.path = save_model(pl_module.model, folder / self.filename, meta)
