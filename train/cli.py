"""The training command line: a LightningCLI over :class:`EgoMotionModule` and any snippet data module.

``python -m ocalib.train fit --config configs/train/synthetic-cpu.yaml`` (or ``ocalib train fit ...``); also
``validate``, ``test`` and resuming with ``--ckpt_path``. Every run checkpoints ``last.ckpt``, logs the learning
rate and writes the slim ``model.pt`` at the end: the weights of its best validation (see :mod:`ocalib.train.callbacks`).
"""

from __future__ import annotations

import re
import sys

import torch
from jsonargparse import ArgumentError
from lightning.fabric.utilities.exceptions import MisconfigurationException
from lightning.pytorch.callbacks import LearningRateMonitor, ModelCheckpoint
from lightning.pytorch.cli import LightningCLI
from ocalib.train.callbacks import ExportModel, ReleaseProcessGroup
from ocalib.train.datamodule import SnippetDataModule
from ocalib.train.module import EgoMotionModule

from ocalib.errors import InputError, read_text


class EgoMotionCLI(LightningCLI):
    """LightningCLI with the model's resolution linked to the data's and a ``threads`` option."""

    def add_arguments_to_parser(self, parser) -> None:
        parser.link_arguments("data.init_args.height", "model.height")
        parser.link_arguments("data.init_args.width", "model.width")
        parser.add_argument(
            "--threads",
            type=int | None,
            default=None,
            help="torch intra-op threads (measured: 1 is several times faster than 2 on a busy 2-core CPU)",
        )

    def instantiate_classes(self) -> None:
        """The classes of the configuration; a value they refuse (an unavailable accelerator, a bad option) is an
        :class:`InputError`, printed by ``ocalib train`` as one line."""
        try:
            super().instantiate_classes()
        except (MisconfigurationException, ValueError) as err:
            if isinstance(err, InputError):
                raise
            raise InputError(f"configuration: {str(err).splitlines()[0]}") from None

    def before_instantiate_classes(self) -> None:
        config = self.config[self.subcommand] if self.subcommand else self.config
        if config.get("threads"):
            torch.set_num_threads(config["threads"])


def trainer_defaults(export: ExportModel | None = None) -> dict:
    return {
        "callbacks": [
            ModelCheckpoint(save_last=True, every_n_train_steps=500),
            LearningRateMonitor("step"),
            export or ExportModel(),
            ReleaseProcessGroup(),
        ],
        "logger": {"class_path": "lightning.pytorch.loggers.TensorBoardLogger", "init_args": {"save_dir": "runs"}},
    }


def main(args: list[str] | None = None, run: bool = True) -> EgoMotionCLI:
    """Run the CLI on ``args`` (None: ``sys.argv[1:]``). A command line the parser refuses, or a config file that is
    missing, a folder or binary, is an :class:`InputError` (one line, where argparse would print the usage); one
    without the data (no ``--config``) says to give a config."""
    argv = sys.argv[1:] if args is None else args
    configs = [
        option.partition("=")[2] or value
        for option, value in zip(argv, [*argv[1:], ""])
        if option == "--config" or option.startswith("--config=")
    ]
    for config in configs:
        read_text(config, "config file")
    export = ExportModel()
    try:
        return EgoMotionCLI(
            EgoMotionModule,
            SnippetDataModule,
            subclass_mode_data=True,
            seed_everything_default=0,
            trainer_defaults=trainer_defaults(export),
            save_config_kwargs={"overwrite": True},
            args=args,
            run=run,
            parser_kwargs={"prog": "ocalib train", "exit_on_error": False},
        )
    except ArgumentError as err:
        message = " ".join(str(err).split())
        missing = re.fullmatch(r"the following arguments are required: (\w+)\.data", message)
        if missing and not configs:  # the data module is the one argument without a default
            message = f"{missing[1]}: give a config, e.g. --config configs/train/quick.yaml"
        raise InputError(message) from None
    except SystemExit:
        if export.interrupted is not None:  # Lightning turns Ctrl-C into exit code 1 after its shutdown
            raise KeyboardInterrupt(export.interrupted) from None
        raise
