"""Every training config parses and instantiates (model, data module, trainer), with the documented choices."""

from pathlib import Path

import pytest
import torch
from ocalib.train.cli import main
from ocalib.train.datamodule import SnippetDataModule
from ocalib.train.synthetic import SyntheticDataModule

from ocalib.models import load_model

CONFIGS = sorted((Path(__file__).parents[2] / "configs" / "train").glob("*.yaml"))
CPU = [
    "--trainer.accelerator=cpu",
    "--trainer.devices=1",
    "--trainer.strategy=auto",
    "--trainer.precision=32-true",
    "--trainer.sync_batchnorm=false",
]


def test_all_configs_are_there():
    names = {p.stem for p in CONFIGS}
    assert {
        "synthetic-cpu",
        "synthetic-cpu-sc",
        "kitti-raw",
        "kitti-odometry",
        "sfmlearner",
        "folder",
        "gpu",
        "finetune",
    } <= names


@pytest.mark.parametrize("config", CONFIGS, ids=lambda p: p.stem)
def test_config_instantiates(config, tmp_path):
    cli = main(["--config", str(config), *CPU, f"--trainer.default_root_dir={tmp_path}"], run=False)
    assert isinstance(cli.datamodule, SnippetDataModule)
    assert (cli.model.hparams.height, cli.model.hparams.width) == (
        cli.datamodule.hparams.height,
        cli.datamodule.hparams.width,
    )
    if config.stem.startswith("synthetic"):
        assert isinstance(cli.datamodule, SyntheticDataModule) and cli.model.hparams.size == "small"
        assert (cli.model.hparams.geometry > 0) == (config.stem == "synthetic-cpu-sc")
    if config.stem == "finetune":  # the shipped model's recipe, from its weights
        shipped = load_model()
        assert (cli.model.hparams.height, cli.model.hparams.width) == (shipped.height, shipped.width)
        assert torch.equal(next(iter(cli.model.model.state_dict().values())), next(iter(shipped.state_dict().values())))
    if config.stem == "gpu":
        assert cli.model.hparams.size == "large"
