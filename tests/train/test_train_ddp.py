"""A 2-process CPU DDP smoke test (gloo, spawned processes): the gpu config's strategy trains and exports; the
process group is released at teardown."""

from types import SimpleNamespace

import pytest
import torch.distributed as dist
from conftest import tiny_args
from lightning.pytorch.trainer.states import TrainerStatus
from ocalib.train.callbacks import ReleaseProcessGroup
from ocalib.train.cli import main

from ocalib.models import load_model


def test_two_process_ddp_fit(tiny_synth, tmp_path):
    out = tmp_path / "runs"
    cli = main(
        [
            "fit",
            *tiny_args(
                tiny_synth,
                out,
                "--trainer.max_steps=2",
                "--trainer.limit_val_batches=0",
                "--trainer.strategy=ddp_spawn",
                "--trainer.devices=2",
                "--data.batch_size=1",
            ),
        ]
    )  # (SyncBatchNorm needs CUDA)
    version = sorted(out.glob("tiny/version_*"))[-1]
    assert (version / "checkpoints" / "last.ckpt").is_file()
    assert load_model(version / "model.pt").size == "small"
    assert cli.trainer.world_size == 2


@pytest.mark.parametrize("status", [TrainerStatus.RUNNING, TrainerStatus.INTERRUPTED])
def test_release_process_group_destroys_it_at_teardown(tmp_path, status):
    """After a finished run (barrier, then destroy) and after an exception (destroy only), no group is left."""
    dist.init_process_group("gloo", init_method=f"file://{tmp_path / 'store'}", rank=0, world_size=1)
    trainer = SimpleNamespace(state=SimpleNamespace(status=status))
    try:
        ReleaseProcessGroup().teardown(trainer, None, "fit")
        assert not dist.is_initialized()
        ReleaseProcessGroup().teardown(trainer, None, "fit")  # nothing to release: a no-op
    finally:
        if dist.is_initialized():  # never leave a group to the next test in this process
            dist.destroy_process_group()
