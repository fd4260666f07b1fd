"""A LightningDataModule of training snippets from any sequence layout, split by sequence.

Convention: samples as :mod:`ocalib.data.snippets` (``image`` (B, S, 3, H, W) target first, ``K`` (B, 3, 3),
``poses`` (B, S, 4, 4) / ``depth`` (B, S, 1, H, W) when every sequence in the batch has them).
Augmentation (training only) is drawn once per snippet and applied to all its frames, K and poses included.
"""

from __future__ import annotations

import random
from pathlib import Path

import lightning.pytorch as pl
import torch
from torch.utils.data import DataLoader

from ocalib.data.augment import SnippetAugmentation
from ocalib.data.layout import find_sequences, open_sequence
from ocalib.data.snippets import SnippetDataset, collate_snippets
from ocalib.errors import InputError


def split_by_sequence(paths: list[Path], val_fraction: float, seed: int) -> tuple[list[Path], list[Path]]:
    """Split sequence folders into (train, val): whole sequences, ``round(val_fraction n)`` (at least one) to val."""
    if val_fraction <= 0:
        return list(paths), []
    if len(paths) < 2:
        raise InputError(
            f"{paths[0] if paths else 'sequences'}: splitting by sequence needs at least two "
            "sequences; give val_sequences or set val_fraction to 0"
        )
    shuffled = sorted(paths)
    random.Random(seed).shuffle(shuffled)
    n_val = min(len(paths) - 1, max(1, round(val_fraction * len(paths))))
    return sorted(shuffled[n_val:]), sorted(shuffled[:n_val])


class SnippetDataModule(pl.LightningDataModule):
    """Snippets of the sequences at ``sequences`` (folders of any layout, folders of sequences, or split
    files such as SfMLearner's ``train.txt``); validation on ``val_sequences`` or, when not given, on a
    ``val_fraction`` of the sequences drawn with ``seed``. A sequence never gives frames to both sets.

    ``cameras``/``intrinsics``: layout options of :func:`ocalib.data.open_sequence`. ``height``/``width``:
    training resolution. ``offsets``: source frames relative to the target. ``static_threshold``: drop snippets
    with less image motion. ``augmentation``: None disables it. ``seed``: the split, the shuffling and the
    workers' augmentation draws (without workers, augmentation uses torch's global RNG: ``seed_everything``).
    ``cache_mb``: decoded frames kept in memory by each loader process and set (0: none); every frame is read by
    several snippets an epoch. 512 MB hold the synthetic presets' 4,800 frames at 64x208 with their depth.
    """

    def __init__(
        self,
        sequences: list[str],
        val_sequences: list[str] | None = None,
        val_fraction: float = 0.1,
        cameras: list[str] | None = None,
        intrinsics: str | None = None,
        height: int = 128,
        width: int = 416,
        offsets: tuple[int, ...] = (-1, 1),
        static_threshold: float = 0.0,
        augmentation: SnippetAugmentation | None = SnippetAugmentation(),
        batch_size: int = 4,
        num_workers: int = 0,
        seed: int = 0,
        cache_mb: float = 512.0,
    ):
        super().__init__()
        self.save_hyperparameters()
        self.augmentation = augmentation
        self.train_paths: list[Path] = []
        self.val_paths: list[Path] = []
        self.train_set: SnippetDataset | None = None
        self.val_set: SnippetDataset | None = None

    def setup(self, stage: str | None = None) -> None:
        if self.train_set is not None:
            return
        h = self.hparams
        paths = [p for s in h.sequences for p in find_sequences(s)]
        if h.val_sequences:
            self.train_paths, self.val_paths = paths, [p for s in h.val_sequences for p in find_sequences(s)]
        else:
            self.train_paths, self.val_paths = split_by_sequence(paths, h.val_fraction, h.seed)
        both = {p.resolve() for p in self.train_paths} & {p.resolve() for p in self.val_paths}
        if both:
            raise InputError(f"{sorted(both)[0]}: a sequence is in both the training and the validation set")
        self.train_set = self._dataset(self.train_paths, self.augmentation)
        self.val_set = self._dataset(self.val_paths, None) if self.val_paths else None

    def _dataset(self, paths: list[Path], transform) -> SnippetDataset:
        h = self.hparams
        sequences = [open_sequence(p, h.cameras, h.intrinsics) for p in paths]
        dataset = SnippetDataset(sequences, h.offsets, (h.height, h.width), h.static_threshold, transform, h.cache_mb)
        if not len(dataset):
            raise InputError(
                f"{paths[0]}: no snippets with offsets {list(h.offsets)} in {len(paths)} sequence(s) "
                "(too few frames, or all filtered as static)"
            )
        return dataset

    def _loader(self, dataset: SnippetDataset, shuffle: bool) -> DataLoader:
        h = self.hparams
        return DataLoader(
            dataset,
            batch_size=h.batch_size,
            shuffle=shuffle,
            num_workers=h.num_workers,
            collate_fn=collate_snippets,
            persistent_workers=h.num_workers > 0,
            generator=torch.Generator().manual_seed(h.seed),
        )

    def train_dataloader(self) -> DataLoader:
        return self._loader(self.train_set, shuffle=True)

    def val_dataloader(self) -> DataLoader | list:
        return self._loader(self.val_set, shuffle=False) if self.val_set is not None else []
