"""Training on the synthetic presets: render them on first use, then train like any other rig sequence.

Sequences are rendered at the training resolution into ``root/<preset>-seed<S>-<H>x<W>-<N>f`` (a finished
folder holds a ``.complete`` marker; an interrupted render is redone). Seeds >= 1000 are reserved for
held-out evaluation and refused here.
"""

from __future__ import annotations

import shutil
from pathlib import Path

from ocalib.train.datamodule import SnippetDataModule

from ocalib.data.augment import SnippetAugmentation
from ocalib.errors import InputError

HELD_OUT_SEEDS = 1000  # seeds >= this are never trained or validated on


def synthetic_folder(root, preset: str, seed: int, height: int, width: int, frames: int) -> Path:
    return Path(root) / f"{preset}-seed{seed}-{height}x{width}-{frames}f"


def ensure_rendered(root, preset: str, seed: int, height: int, width: int, frames: int, workers: int = 1) -> Path:
    """Render preset ``preset`` with ``seed`` unless already there; returns the sequence folder."""
    from ocalib.synth import preset as get_preset
    from ocalib.synth import render_sequence

    if seed >= HELD_OUT_SEEDS:
        raise InputError(f"synthetic seed {seed}: seeds >= {HELD_OUT_SEEDS} are reserved for held-out evaluation")
    out = synthetic_folder(root, preset, seed, height, width, frames)
    if (out / ".complete").is_file():
        return out
    cfg = get_preset(preset).with_overrides(seed=seed, height=height, width=width, frames=frames)
    partial = out.with_name(out.name + ".partial")
    shutil.rmtree(partial, ignore_errors=True)
    render_sequence(cfg, partial, workers=workers)
    (partial / ".complete").touch()
    shutil.rmtree(out, ignore_errors=True)
    partial.rename(out)
    return out


class SyntheticDataModule(SnippetDataModule):
    """:class:`SnippetDataModule` over rendered presets: ``presets`` maps a preset to its training seeds,
    ``val_presets`` to its validation seeds (``frames`` / ``val_frames`` frames each). Give each preset its own
    seeds: presets with the same trajectory kind and seed drive the same street (their front cameras would see
    the same images). Rendering happens in ``prepare_data`` (``render_workers`` processes). Other arguments as
    :class:`SnippetDataModule`. ``presets`` may also be a list of preset names sharing ``seeds`` and
    ``val_seeds`` (the form of older configs).
    """

    def __init__(
        self,
        presets: dict[str, list[int]] | list[str] = {  # noqa: B006 - read only
            "handheld": [0, 1],
            "front-left": [2, 3],
            "front-rear": [4, 5],
            "stereo": [6, 7],
        },
        val_presets: dict[str, list[int]] | None = {  # noqa: B006 - read only
            "handheld": [500],
            "front-left": [501],
            "front-rear": [502],
            "stereo": [503],
        },
        seeds: list[int] | None = None,
        val_seeds: list[int] | None = None,
        frames: int = 150,
        val_frames: int = 60,
        root: str = "data/synth",
        render_workers: int = 2,
        height: int = 64,
        width: int = 208,
        offsets: tuple[int, ...] = (-1, 1),
        static_threshold: float = 0.0,
        augmentation: SnippetAugmentation | None = SnippetAugmentation(),
        batch_size: int = 4,
        num_workers: int = 0,
        seed: int = 0,
        cache_mb: float = 512.0,
    ):
        if not isinstance(presets, dict):  # a list of presets sharing ``seeds`` / ``val_seeds`` (older configs)
            if seeds is None:
                raise InputError(
                    f"synthetic presets {list(presets)}: a list of presets needs seeds (or map each preset to its seeds)"
                )
            presets, val_presets = {p: list(seeds) for p in presets}, {p: list(val_seeds or []) for p in presets}
        self.renders = [(p, s, frames) for p, ss in presets.items() for s in ss]
        self.val_renders = [(p, s, val_frames) for p, ss in (val_presets or {}).items() for s in ss]
        for p, s, _ in self.renders + self.val_renders:
            if s >= HELD_OUT_SEEDS:
                raise InputError(
                    f"synthetic seed {s} ({p}): seeds >= {HELD_OUT_SEEDS} are reserved for held-out evaluation"
                )
        both = {(p, s) for p, s, _ in self.renders} & {(p, s) for p, s, _ in self.val_renders}
        if both:
            raise InputError(f"synthetic sequences {sorted(both)} are in both presets and val_presets")
        folder = lambda p, s, n: str(synthetic_folder(root, p, s, height, width, n))  # noqa: E731
        folders = dict(
            sequences=[folder(*r) for r in self.renders],
            val_sequences=[folder(*r) for r in self.val_renders] or None,
            val_fraction=0.0,
        )
        super().__init__(
            **folders,
            height=height,
            width=width,
            offsets=offsets,
            static_threshold=static_threshold,
            augmentation=augmentation,
            batch_size=batch_size,
            num_workers=num_workers,
            seed=seed,
            cache_mb=cache_mb,
        )
        self.hparams.update(folders, cameras=None, intrinsics=None)  # save_hyperparameters saw this class's arguments
        self.root, self.render_workers = root, render_workers

    def prepare_data(self) -> None:
        h = self.hparams
        for preset, seed, frames in self.renders + self.val_renders:
            ensure_rendered(self.root, preset, seed, h.height, h.width, frames, self.render_workers)
