"""The learning-rate schedule: warm-up, cosine decay over the steps, and over the time limit when that runs out first."""

import math

import lightning.pytorch as pl
import pytest
from lightning.pytorch.callbacks import Timer
from ocalib.train.module import EgoMotionModule, lr_factor
from ocalib.train.synthetic import SyntheticDataModule


def cosine(progress: float, low: float) -> float:
    return low + (1 - low) * (1 + math.cos(math.pi * progress)) / 2


def test_warm_up_then_cosine_over_the_steps():
    assert lr_factor(0, 100, 10, 0.05) == pytest.approx(0.1)
    assert lr_factor(9, 100, 10, 0.05) == pytest.approx(1.0)
    assert lr_factor(10, 100, 10, 0.05) == pytest.approx(1.0)
    assert lr_factor(55, 100, 10, 0.05) == pytest.approx(cosine(0.5, 0.05))
    assert lr_factor(100, 100, 10, 0.05) == pytest.approx(0.05)
    assert lr_factor(500, 100, 10, 0.05) == pytest.approx(0.05)  # past the end: held at the floor


def test_a_time_limit_that_runs_out_first_sets_the_progress():
    # step 20 of 100 (a fifth of the decay) but 80 % of the time spent: the schedule is at 80 %
    assert lr_factor(30, 110, 10, 0.05, time_spent=0.8) == pytest.approx(cosine(0.8, 0.05))
    assert lr_factor(30, 110, 10, 0.05, time_spent=0.1) == pytest.approx(cosine(0.2, 0.05))  # the steps lead
    assert lr_factor(30, 110, 10, 0.05, time_spent=1.3) == pytest.approx(0.05)
    assert lr_factor(3, 110, 10, 0.05, time_spent=0.9) == pytest.approx(0.4)  # the warm-up counts steps only


def test_the_trainer_anneals_by_its_max_time(tiny_synth, tmp_path):
    """A run resumed with 90 % of its ``max_time`` spent steps at the cosine's 90 % point, not its first steps'."""
    pl.seed_everything(0)
    dm = SyntheticDataModule(
        presets={"handheld": [0]},
        val_presets={},
        frames=6,
        root=str(tiny_synth),
        height=32,
        width=96,
        batch_size=2,
        augmentation=None,
    )
    module = EgoMotionModule(height=32, width=96, lr=1e-3, warmup_steps=0, min_lr_ratio=0.05)
    lrs = []

    class Record(pl.Callback):
        def on_train_batch_start(self, trainer, pl_module, batch, batch_idx):  # the rate this step uses
            lrs.append(trainer.optimizers[0].param_groups[0]["lr"])

    trainer = pl.Trainer(
        accelerator="cpu",
        max_steps=1000,
        max_time={"seconds": 1000},
        limit_val_batches=0,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        callbacks=[Record()],
        default_root_dir=tmp_path,
        limit_train_batches=3,
        max_epochs=1,
    )
    timer = next(c for c in trainer.callbacks if isinstance(c, Timer))
    timer.load_state_dict({"time_elapsed": {"train": 900.0}})  # as a checkpoint of a run 15 min in restores it
    trainer.fit(module, datamodule=dm)
    # the steps alone (0, 1, 2 of 3) would give 1e-3 x cosine(0, 1/3, 2/3); the time limit puts the schedule at 90 %
    assert len(lrs) == 3
    for lr in lrs:
        assert 1e-3 * cosine(0.92, 0.05) < lr <= 1e-3 * cosine(0.9, 0.05)
    assert lrs == sorted(lrs, reverse=True)
