import pytest
import torch

# Many small ops: intra-op threads only add contention on the shared 2-core machine.
torch.set_num_threads(1)


@pytest.fixture(scope="session")
def tiny_synth(tmp_path_factory):
    """Root folder with tiny renders (32x96) of the handheld preset: seed 0 (6 frames) and seed 500 (4 frames)."""
    from ocalib.train.synthetic import ensure_rendered

    root = tmp_path_factory.mktemp("synth")
    ensure_rendered(root, "handheld", 0, 32, 96, 6)
    ensure_rendered(root, "handheld", 500, 32, 96, 4)
    return root


def tiny_args(root, out, *extra) -> list[str]:
    """LightningCLI arguments of a tiny synthetic run (no augmentation, no sanity check, few steps)."""
    return [
        "--trainer.accelerator=cpu",
        "--trainer.enable_model_summary=false",
        "--trainer.num_sanity_val_steps=0",
        f"--trainer.default_root_dir={out}",
        "--trainer.logger.class_path=lightning.pytorch.loggers.TensorBoardLogger",
        f"--trainer.logger.init_args.save_dir={out}",
        "--trainer.logger.init_args.name=tiny",
        "--trainer.enable_progress_bar=false",
        "--trainer.log_every_n_steps=1",
        "--data=ocalib.train.synthetic.SyntheticDataModule",
        f"--data.root={root}",
        "--data.presets={handheld: [0]}",
        "--data.val_presets={handheld: [500]}",
        "--data.frames=6",
        "--data.val_frames=4",
        "--data.height=32",
        "--data.width=96",
        "--data.batch_size=2",
        "--data.augmentation=null",
        "--data.render_workers=1",
        "--model.warmup_steps=1",
        "--model.image_interval=2",
        *extra,
    ]
