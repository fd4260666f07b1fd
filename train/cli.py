"""The training command line: a LightningCLI over :class:`EgoMotionModule` and any snippet data module.

``python -m ocalib.train fit --config configs/train/synthetic-cpu.yaml`` (or ``ocalib train fit ...``); also
``validate``, ``test`` and resuming with ``--ckpt_path``. Every run checkpoints ``last.ckpt``, logs the learning
rate and writes the slim ``model.pt`` at the end: the weights of its best validation (see :mod:`ocalib.train.callbacks`).
"""

from __future__ import annotations

import torch
from lightning.pytorch.callbacks import LearningRateMonitor, ModelCheckpoint
from lightning.pytorch.cli import LightningCLI

from ocalib.train.callbacks import ExportModel, ReleaseProcessGroup
from ocalib.train.datamodule import SnippetDataModule
from ocalib.train.module import EgoMotionModule


class EgoMotionCLI(LightningCLI):
    """LightningCLI with the model's resolution linked to the data's and a ``threads`` option."""

    def add_arguments_to_parser(self, parser) -> None:
        parser.link_arguments("data.init_args.height", "model.height")
        parser.link_arguments("data.init_args.width", "model.width")
        parser.add_argument("--threads", type=int | None, default=None,
                            help="torch intra-op threads (measured: 1 is several times faster than 2 on a busy 2-core CPU)")

    def before_instantiate_classes(self) -> None:
        config = self.config[self.subcommand] if self.subcommand else self.config
        if config.get("threads"):
            torch.set_num_threads(config["threads"])


def trainer_defaults() -> dict:
    return {
        "callbacks": [ModelCheckpoint(save_last=True, every_n_train_steps=500), LearningRateMonitor("step"),
                      ExportModel(), ReleaseProcessGroup()],
        "logger": {"class_path": "lightning.pytorch.loggers.TensorBoardLogger", "init_args": {"save_dir": "runs"}},
    }


def main(args: list[str] | None = None, run: bool = True) -> EgoMotionCLI:
    """Run the CLI on ``args`` (None: ``sys.argv[1:]``)."""
    return EgoMotionCLI(EgoMotionModule, SnippetDataModule, subclass_mode_data=True, seed_everything_default=0,
                        trainer_defaults=trainer_defaults(), save_config_kwargs={"overwrite": True}, args=args,
                        run=run, parser_kwargs={"prog": "ocalib train"})
