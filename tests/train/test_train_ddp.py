"""A 2-process CPU DDP smoke test (gloo, spawned processes): the gpu config's strategy trains and exports."""

from pathlib import Path

from conftest import tiny_args

from ocalib.models import load_model
from train.cli import main


def test_two_process_ddp_fit(tiny_synth, tmp_path):
    out = tmp_path / "runs"
    cli = main(["fit", *tiny_args(tiny_synth, out, "--trainer.max_steps=2", "--trainer.limit_val_batches=0",
                                  "--trainer.strategy=ddp_spawn", "--trainer.devices=2",
                                  "--data.batch_size=1")])  # (SyncBatchNorm needs CUDA)
    version = sorted(out.glob("tiny/version_*"))[-1]
    assert (version / "checkpoints" / "last.ckpt").is_file()
    assert load_model(version / "model.pt").size == "small"
    assert cli.trainer.world_size == 2
