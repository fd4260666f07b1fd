"""The snippet datamodule: split by sequence, one augmentation per snippet with K and poses updated, YAML config."""

from pathlib import Path

import cv2
import lightning.pytorch as pl
import numpy as np
import pytest
import torch
from jsonargparse import ArgumentParser
from ocalib.train.datamodule import SnippetDataModule, split_by_sequence

from ocalib.data.rig import CameraSpec, RigSpec, write_rig_yaml
from ocalib.errors import InputError
from ocalib.io.poses import write_kitti

H, W = 48, 160
K = np.array([[60.0, 0, 79.5], [0, 60, 23.5], [0, 0, 1]])
POINT = np.array([0.3, 0.1, 5.0, 1.0])  # in the world = camera 0's first frame


def poses(n: int) -> np.ndarray:
    """Camera-to-world: moving 0.2 m/frame forward and 0.05 m/frame right, turning 0.03 rad/frame about y."""
    out = np.tile(np.eye(4), (n, 1, 1))
    for t in range(n):
        c, s = np.cos(0.03 * t), np.sin(0.03 * t)
        out[t, :3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
        out[t, :3, 3] = [0.05 * t, 0, 0.2 * t]
    return out


def write_blob_rig(root: Path, n: int = 4, static: bool = False) -> Path:
    """A one-camera rig whose frames show a bright blob at the projection of POINT (or all the same frame)."""
    write_rig_yaml(_mkdir(root) / "rig.yaml", RigSpec([CameraSpec("cam0", W, H, K)]))
    v, u = np.mgrid[:H, :W]
    P = poses(n)
    for t in range(n):
        x = K @ (np.linalg.inv(P[0 if static else t]) @ POINT)[:3]
        blob = np.exp(-((u - x[0] / x[2]) ** 2 + (v - x[1] / x[2]) ** 2) / 8)
        assert cv2.imwrite(
            str(_mkdir(root / "cam0" / "images") / f"{t:06d}.png"), np.round(255 * blob).astype(np.uint8)
        )
    write_kitti(root / "cam0" / "poses.txt", P)
    return root


def _mkdir(path: Path) -> Path:
    path.mkdir(parents=True, exist_ok=True)
    return path


def centroid(g: torch.Tensor) -> np.ndarray:
    v, u = torch.meshgrid(torch.arange(g.shape[0] * 1.0), torch.arange(g.shape[1] * 1.0), indexing="ij")
    return (torch.stack([(g * u).sum(), (g * v).sum()]) / g.sum()).numpy()


def test_split_by_sequence(tmp_path):
    for k in range(5):
        write_blob_rig(tmp_path / f"seq{k}", n=3)
    dm = SnippetDataModule([str(tmp_path)], val_fraction=0.4, height=24, width=80, batch_size=2, seed=1)
    dm.setup("fit")
    assert len(dm.train_paths) == 3 and len(dm.val_paths) == 2
    assert not {p.name for p in dm.train_paths} & {p.name for p in dm.val_paths}
    train_names = {n for b in dm.train_dataloader() for n in b["sequence"]}
    val_names = {n for b in dm.val_dataloader() for n in b["sequence"]}
    assert train_names == {p.name for p in dm.train_paths} and val_names == {p.name for p in dm.val_paths}
    again = SnippetDataModule([str(tmp_path)], val_fraction=0.4, seed=1)
    again.setup("fit")
    assert again.val_paths == dm.val_paths  # the seed fixes the split


def test_split_needs_two_sequences_and_no_overlap(tmp_path):
    write_blob_rig(tmp_path / "a", n=3)
    write_blob_rig(tmp_path / "b", n=3)
    with pytest.raises(InputError, match="two"):
        split_by_sequence([tmp_path / "a"], 0.2, 0)
    assert split_by_sequence([tmp_path / "a"], 0.0, 0) == ([tmp_path / "a"], [])
    dm = SnippetDataModule([str(tmp_path)], val_sequences=[str(tmp_path / "b")])
    with pytest.raises(InputError, match="both"):
        dm.setup("fit")


def test_same_augmentation_on_every_frame_of_a_snippet(tmp_path):
    write_blob_rig(tmp_path / "still", n=5, static=True)
    write_blob_rig(tmp_path / "other", n=5)
    torch.manual_seed(0)
    dm = SnippetDataModule(
        [str(tmp_path / "still")],
        val_sequences=[str(tmp_path / "other")],
        height=H,
        width=W,
        offsets=(-2, -1, 1, 2),
        batch_size=8,
    )
    dm.setup("fit")
    batch = next(iter(dm.train_dataloader()))
    assert batch["image"].shape == (1, 5, 3, H, W)
    image = batch["image"][0]
    for s in range(1, 5):
        assert torch.equal(image[s], image[0])
    assert not torch.allclose(batch["K"][0], torch.from_numpy(K).float())  # cropped (zoom > 1 almost surely)


@pytest.mark.parametrize("flip_p", [0.0, 1.0])
def test_augmented_K_and_poses_project_the_point(tmp_path, flip_p):
    """The blob of every frame lies where the augmented K and poses project the (mirrored, if flipped) point."""
    write_blob_rig(tmp_path / "a", n=4)
    torch.manual_seed(1)
    aug = dict(brightness=0.0, contrast=0.0, saturation=0.0, hue=0.0, flip_p=flip_p, max_zoom=1.4)
    parser = ArgumentParser()
    parser.add_class_arguments(SnippetDataModule, "data")
    cfg = parser.parse_object(
        {
            "data": {
                "sequences": [str(tmp_path / "a")],
                "val_fraction": 0.0,
                "height": 36,
                "width": 120,
                "batch_size": 2,
                "augmentation": aug,
            }
        }
    )
    dm = parser.instantiate(cfg).data
    dm.setup("fit")
    assert dm.val_dataloader() == []
    mirror = np.diag([-1.0, 1, 1, 1]) if flip_p else np.eye(4)
    P = poses(4)
    for batch in dm.train_dataloader():
        for b in range(len(batch["frame"])):
            point = mirror @ np.linalg.inv(P[batch["frame"][b]]) @ POINT  # in the target camera's frame
            for s in range(3):
                x = batch["K"][b].double().numpy() @ (np.linalg.inv(batch["poses"][b, s].double().numpy()) @ point)[:3]
                np.testing.assert_allclose(centroid(batch["image"][b, s, 0]), x[:2] / x[2], atol=0.15)


class _Tiny(pl.LightningModule):
    def __init__(self):
        super().__init__()
        self.w = torch.nn.Parameter(torch.zeros(1))

    def training_step(self, batch, _):
        return (batch["image"].mean() - self.w).pow(2)

    def validation_step(self, batch, _):
        self.log("val", batch["image"].mean(), batch_size=len(batch["frame"]))

    def configure_optimizers(self):
        return torch.optim.SGD(self.parameters(), lr=0.1)


def test_trains_with_lightning(tmp_path):
    for k in range(3):
        write_blob_rig(tmp_path / f"seq{k}", n=3)
    dm = SnippetDataModule([str(tmp_path)], val_fraction=0.3, height=24, width=80, batch_size=2)
    trainer = pl.Trainer(
        fast_dev_run=True,
        accelerator="cpu",
        logger=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        default_root_dir=tmp_path,
    )
    trainer.fit(_Tiny(), datamodule=dm)
    assert trainer.state.finished


def test_too_short_sequences_are_a_clear_error(tmp_path):
    write_blob_rig(tmp_path / "a", n=2)
    dm = SnippetDataModule([str(tmp_path / "a")], val_fraction=0.0, offsets=(-1, 1))
    with pytest.raises(InputError, match="no snippets"):
        dm.setup("fit")
