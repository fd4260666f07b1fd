"""Contact sheets of the presets: a few frames of every camera, image and depth side by side.

``python -m ocalib.synth.contact_sheet [--preset NAME ...] [--out docs/synth]`` writes ``<out>/<preset>.png``.
Depth is shown as a turbo colour map of inverse depth (near = red, far = blue, sky = black).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
import torch

from ocalib.synth.presets import PRESETS, preset
from ocalib.synth.sequence import frames
from ocalib.synth.writer import to_rgb8


def depth_colour(depth: torch.Tensor, near: float = 2.0) -> np.ndarray:
    """(H, W) metres -> (H, W, 3) uint8 RGB turbo map of ``near / depth``; 0 (sky) is black."""
    d = depth.cpu().numpy()
    inv = np.where(d > 0, np.clip(near / np.maximum(d, 1e-6), 0, 1), 0)
    bgr = cv2.applyColorMap((np.sqrt(inv) * 255).astype(np.uint8), cv2.COLORMAP_TURBO)
    bgr[d <= 0] = 0
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def contact_sheet(name: str, rows: int = 4, step: int = 25, height: int = 128, width: int = 416) -> np.ndarray:
    """An RGB sheet (rows x (2 x cameras) tiles) of preset ``name``: frames 0, step, 2 step, ..."""
    cfg = preset(name).with_overrides(frames=(rows - 1) * step + 1, height=height, width=width)
    gap = 4
    lines = []
    for n, views in frames(cfg, indices=range(0, cfg.frames, step)):
        tiles = []
        for cam, (image, depth) in zip(cfg.cameras, views):
            rgb = np.ascontiguousarray(to_rgb8(image))
            cv2.putText(
                rgb, f"{cam.name}  frame {n}", (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 1, cv2.LINE_AA
            )
            tiles += [
                rgb,
                np.full((height, gap, 3), 255, np.uint8),
                depth_colour(depth),
                np.full((height, 3 * gap, 3), 255, np.uint8),
            ]
        lines += [np.hstack(tiles[:-1]), np.full((gap, sum(t.shape[1] for t in tiles[:-1]), 3), 255, np.uint8)]
    return np.vstack(lines[:-1])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", nargs="*", default=list(PRESETS), help="presets (default: all)")
    parser.add_argument("--out", default="docs/synth", help="output folder")
    parser.add_argument("--rows", type=int, default=4)
    parser.add_argument("--step", type=int, default=25, help="frames between rows")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name in args.preset:
        sheet = contact_sheet(name, args.rows, args.step)
        cv2.imwrite(str(out / f"{name}.png"), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))
        print(f"wrote {out / f'{name}.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
