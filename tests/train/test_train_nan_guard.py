"""The NaN guard: a step with a non-finite loss or gradient changes no weight, is counted, and training goes on."""

import lightning.pytorch as pl
import torch
from ocalib.train.module import EgoMotionModule
from torch.utils.data import DataLoader

H, W = 32, 96


def snippet(bad: bool = False) -> dict:
    g = torch.Generator().manual_seed(0)
    image = torch.rand(3, 3, H, W, generator=g)
    if bad:
        image[1, :, 5, 5] = float("nan")
    K = torch.tensor([[55.0, 0, 47.5], [0, 60.0, 15.5], [0, 0, 1]])
    return {"image": image, "K": K}


def test_nonfinite_loss_step_is_skipped(tmp_path):
    pl.seed_everything(0)
    batches = [snippet(), snippet(bad=True), snippet()]
    module = EgoMotionModule(height=H, width=W, warmup_steps=1)
    seen = []

    class Watch(pl.Callback):
        def on_train_batch_start(self, trainer, pl_module, batch, batch_idx):
            seen.append({k: v.clone() for k, v in pl_module.model.state_dict().items()})

    trainer = pl.Trainer(
        accelerator="cpu",
        max_epochs=1,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        callbacks=[Watch()],
        default_root_dir=tmp_path,
    )
    trainer.fit(module, DataLoader(batches, batch_size=1))
    assert module.nonfinite_steps == 1 and len(seen) == 3
    assert all(torch.equal(seen[1][k], seen[2][k]) for k in seen[1])  # the NaN batch changed nothing, BN stats included
    assert not torch.equal(seen[0]["pose_net.head.4.weight"], seen[1]["pose_net.head.4.weight"])  # good ones did
    assert all(torch.isfinite(p).all() for p in module.parameters())


def test_nonfinite_gradient_is_dropped():
    module = EgoMotionModule(height=H, width=W)
    optimizer = torch.optim.SGD(module.parameters(), lr=1.0)
    for p in module.parameters():
        p.grad = torch.zeros_like(p)
    next(module.parameters()).grad.fill_(float("inf"))
    module.log = lambda *a, **k: None  # outside a Trainer
    module.on_before_optimizer_step(optimizer)
    assert module.nonfinite_steps == 1 and all(p.grad is None for p in module.parameters())
