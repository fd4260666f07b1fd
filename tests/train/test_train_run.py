"""The training application end to end on tiny renders: the CLI fits, checkpoints, resumes and exports; an
overfit run's loss falls."""

from pathlib import Path

import lightning.pytorch as pl
import pytest
import torch
from conftest import tiny_args
from ocalib.train.cli import main
from ocalib.train.module import EgoMotionModule
from ocalib.train.synthetic import SyntheticDataModule

from ocalib.cli import main as ocalib_main
from ocalib.errors import InputError
from ocalib.models import load_model


def test_fit_checkpoint_resume_and_export(tiny_synth, tmp_path):
    out = tmp_path / "runs"
    cli = main(["fit", *tiny_args(tiny_synth, out, "--trainer.max_steps=2", "--trainer.val_check_interval=2")])
    assert cli.trainer.global_step == 2
    version = Path(cli.trainer.log_dir)
    last = version / "checkpoints" / "last.ckpt"
    assert last.is_file() and (version / "model.pt").is_file()
    metrics = cli.trainer.callback_metrics
    assert {"val/abs_rel", "val/rotation_error_deg", "val/direction_error_deg", "val/rotation_gain_y"} <= set(metrics)
    assert {"train/gauge", "train/depth_median", "train/depth_far_share"} <= set(metrics)  # the depth's scale
    assert 0.1 < metrics["train/depth_median"] < 100 and 0 <= metrics["train/depth_far_share"] <= 1
    assert list(version.glob("events.out.tfevents.*"))
    recipe = torch.load(version / "model.pt", weights_only=False)["meta"]["hparams"]  # the recipe, lists included
    assert recipe["align"] == list(cli.model.hparams.align) and recipe["distill"] == cli.model.hparams.distill

    assert torch.load(version / "model.pt", weights_only=False)["meta"]["selected"]["global_step"] == 2

    # resume through `ocalib train`: the step count continues from the checkpoint; the resumed run validates
    # nothing, so its model.pt keeps the best validated weights, step 2's, carried in the checkpoint
    assert (
        ocalib_main(
            [
                "train",
                "fit",
                *tiny_args(
                    tiny_synth, out, "--trainer.max_steps=4", "--trainer.limit_val_batches=0", f"--ckpt_path={last}"
                ),
            ]
        )
        == 0
    )
    resumed = sorted(out.glob("tiny/version_*/checkpoints/last.ckpt"))[-1]
    assert torch.load(resumed, weights_only=True)["global_step"] == 4
    exported = torch.load(resumed.parent.parent / "model.pt", weights_only=False)["meta"]
    assert exported["global_step"] == 4 and exported["selected"]["global_step"] == 2

    # the Lightning checkpoint of step 2 and the slim file load to the same model
    ckpt_model, slim = load_model(last), load_model(resumed.parent.parent / "model.pt")
    assert (ckpt_model.height, ckpt_model.width) == (32, 96)
    image = torch.rand(1, 3, 32, 96)
    with torch.no_grad():
        torch.testing.assert_close(ckpt_model.depth(image), slim.depth(image), rtol=0, atol=0)
        torch.testing.assert_close(ckpt_model.pose(image, image), slim.pose(image, image), rtol=0, atol=0)


def test_export_writes_the_best_validated_weights(tmp_path):
    """ExportModel against a record of the validations: the weights of the lowest ``val/abs_rel`` are written,
    sanity checks and non-finite scores are ignored, the choice survives a checkpoint, and without any validation
    the last weights are written."""
    from types import SimpleNamespace

    from ocalib.train.callbacks import ExportModel

    from ocalib.models import EgoMotionModel

    torch.manual_seed(0)
    module = SimpleNamespace(model=EgoMotionModel("small", 32, 96), hparams={"lr": 1e-3})
    trainer = SimpleNamespace(
        sanity_checking=False,
        global_step=0,
        current_epoch=0,
        log_dir=str(tmp_path),
        default_root_dir=str(tmp_path),
        is_global_zero=True,
        callback_metrics={},
    )
    export, weights = ExportModel(), {}
    for step, score, sanity in [
        (0, 0.1, True),
        (10, 0.30, False),
        (20, 0.20, False),
        (30, float("nan"), False),
        (40, 0.25, False),
    ]:
        with torch.no_grad():  # new weights at every validation
            for p in module.model.parameters():
                p.add_(torch.randn_like(p))
        weights[step] = {k: v.clone() for k, v in module.model.state_dict().items()}
        trainer.global_step, trainer.sanity_checking = step, sanity
        trainer.callback_metrics = {"val/abs_rel": torch.tensor(score)}
        export.on_validation_end(trainer, module)
    trainer.global_step = 45

    resumed = ExportModel()
    resumed.load_state_dict(export.state_dict())  # the checkpoint's round trip
    resumed.on_fit_end(trainer, module)
    saved = torch.load(resumed.path, weights_only=False)
    assert saved["meta"]["selected"] == {
        "weights": "lowest val/abs_rel",
        "global_step": 20,
        "val/abs_rel": pytest.approx(0.2),
    }
    assert saved["meta"]["global_step"] == 45
    for k, v in weights[20].items():
        torch.testing.assert_close(saved["state_dict"][k], v.float() if v.is_floating_point() else v)
    assert any(not torch.equal(saved["state_dict"][k], v) for k, v in weights[40].items() if v.is_floating_point())

    unvalidated = ExportModel("last.pt")
    unvalidated.on_fit_end(trainer, module)
    last = torch.load(unvalidated.path, weights_only=False)
    assert last["meta"]["selected"] == {"weights": "last", "global_step": 45}
    for k, v in module.model.state_dict().items():
        torch.testing.assert_close(last["state_dict"][k], v.float() if v.is_floating_point() else v)


@pytest.mark.parametrize("align, precision", [((), "32-true"), ((2, 2), "32-true"), ((2, 2), "bf16-mixed")])
def test_overfit_one_batch_loss_falls(tiny_synth, tmp_path, align, precision):
    """With ``align``, the depth learns from the refined motions and the pose net from its own photometric term.
    ``bf16-mixed`` (configs/train/gpu.yaml's precision, here on the CPU): the step runs and learns."""
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
    module = EgoMotionModule(height=32, width=96, lr=2e-3, warmup_steps=1, min_lr_ratio=1.0, align=align)
    losses = []

    class Record(pl.Callback):
        def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx):
            losses.append(float(outputs["loss"]))

    trainer = pl.Trainer(
        accelerator="cpu",
        max_steps=25,
        overfit_batches=1,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        callbacks=[Record()],
        default_root_dir=tmp_path,
        precision=precision,
    )
    trainer.fit(module, datamodule=dm)
    assert len(losses) == 25
    # measured: 0.08 -> 0.03 alone; 0.12 -> 0.075 with the pose net's own photometric term (depth detached) added
    assert sum(losses[-3:]) < (0.75 if align else 0.6) * sum(losses[:3]), losses
    assert ("train/pose_photometric" in trainer.callback_metrics) == bool(align)


def test_held_out_seeds_are_refused(tmp_path):
    with pytest.raises(InputError, match="1000 \\(stereo\\): seeds >= 1000 are reserved"):
        SyntheticDataModule(presets={"handheld": [0], "stereo": [1000]}, root=str(tmp_path))
    with pytest.raises(InputError, match="in both"):
        SyntheticDataModule(presets={"handheld": [0]}, val_presets={"handheld": [0]}, root=str(tmp_path))


def test_distill_term_is_the_distance_to_the_refined_motions(tiny_synth):
    """``distill``: the term is the pose net's distance to its motions refined by the alignment, computed here
    from the module's parts, and it enters the total with its weight."""
    import math

    from ocalib.frontend.align import align_motion
    from ocalib.geometry.pose import invert_pose
    from ocalib.losses.motion import motion_distance
    from ocalib.models import disp_to_depth

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
    dm.setup("fit")
    batch = next(iter(dm.train_dataloader()))
    totals = {}
    for weight in (0.0, 0.5):
        torch.manual_seed(0)
        module = EgoMotionModule(height=32, width=96, geometry=0.0, align=(2, 2), distill=weight).train()
        with torch.no_grad():
            out, _, T = module.step(batch)
        totals[weight] = out.total
    assert "pose_distill" in out.terms
    images, K = batch["image"], batch["K"]
    B, S = images.shape[:2]
    with torch.no_grad():
        depth = disp_to_depth(module.model.disparities(images[:, 0])[0]).repeat_interleave(S - 1, 0)
        targets = images[:, :1].expand(-1, S - 1, -1, -1, -1).flatten(0, 1)
        refined, _ = align_motion(
            targets,
            images[:, 1:].flatten(0, 1),
            depth,
            K.repeat_interleave(S - 1, 0),
            invert_pose(T).flatten(0, 1),
            iterations=(2, 2),
            max_rotation_deg=math.inf,
        )
        rotation, translation = motion_distance(T.flatten(0, 1), invert_pose(refined))
    expected = rotation.mean() + translation.mean()
    assert expected > 0
    torch.testing.assert_close(out.terms["pose_distill"], expected)
    torch.testing.assert_close(totals[0.5] - totals[0.0], 0.5 * expected)
    with pytest.raises(ValueError, match="only with model.align"):
        EgoMotionModule(height=32, width=96, distill=0.1)


def test_init_from_starts_from_the_models_weights(tiny_synth, tmp_path):
    """``model.init_from``: the module starts from a model file's weights (the shipped one by name), whatever the
    training resolution; a model of another size, or a missing file, is one line and exit 2 from the command."""
    shipped = load_model()
    module = EgoMotionModule(height=32, width=96, init_from="default")
    for name, value in shipped.state_dict().items():
        torch.testing.assert_close(module.model.state_dict()[name], value, rtol=0, atol=0, msg=name)
    fresh = EgoMotionModule().model.state_dict()
    assert not all(torch.equal(fresh[name], value) for name, value in shipped.state_dict().items())
    with pytest.raises(InputError, match="a 'small' model; set model.size: small"):
        EgoMotionModule(size="large", init_from="default")
    args = tiny_args(tiny_synth, tmp_path, "--trainer.max_steps=1", f"--model.init_from={tmp_path / 'none.pt'}")
    assert ocalib_main(["train", "fit", *args]) == 2
