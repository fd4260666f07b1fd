"""Lens distortion through the rig bundle adjustment: the same held-out rig rendered through a pinhole, a fisheye and
an OpenCV (radial-tangential) lens, and the distorted renders given as pinholes.

Each held-out sequence is rendered by ``ocalib synth`` three times with the same seed (the lens on every camera);
each render goes through ``ocalib calibrate``'s on-line pass (network front end) and the rig bundle adjustment with
camera 0's rendered poses as the metric trajectory (:func:`bench_rigba.run`). The ``as-pinhole`` rows read a distorted
render with the lens left out of its rig.yaml, as a user who forgot it would. Reported per run: the bundle
adjustment's rotation error (deg), translation direction error (deg; in the ground plane on cars) and translation
error over the baseline, whether it was trusted, its warnings, and the ratio of each error to the pinhole's.

    python bench/bench_lens.py [--sequences handheld-1007 front-left-1008] [--frames 300] [--workers 2 --threads 2]
"""

from __future__ import annotations

import argparse
import dataclasses
import re
import shutil
from pathlib import Path

import torch
from bench_rigba import run
from common import add_sequence_arguments, write_json

from ocalib.data.distortion import Distortion
from ocalib.data.rig import read_rig_yaml, write_rig_yaml
from ocalib.rigba.options import BundleOptions
from ocalib.synth import preset, render_sequence

LENSES = {
    "pinhole": None,
    "fisheye": Distortion("fisheye", (0.05, -0.01, 0.002, -0.001)),
    "opencv": Distortion("opencv", (-0.25, 0.05, 0.001, -0.001, 0.0)),
}
KEYS = ("rotation_deg", "direction_deg", "translation_rel_baseline")


def render(root: Path, name: str, lens: str, frames: int, workers: int = 2) -> Path:
    """``name`` (PRESET-SEED, a held-out seed) rendered at 128x416 through ``lens`` on every camera, under ``root``."""
    path = root / f"{name}-{lens}"
    if (path / "rig.yaml").exists():
        return path
    kind, seed = re.fullmatch(r"(.+)-(\d+)", name).groups()
    cfg = preset(kind).with_overrides(frames=frames, seed=int(seed), height=128, width=416)
    cfg = cfg.with_overrides(cameras=[dataclasses.replace(c, distortion=LENSES[lens]) for c in cfg.cameras])
    partial = path.with_name(path.name + ".partial")
    shutil.rmtree(partial, ignore_errors=True)
    render_sequence(cfg, partial, workers=workers)
    partial.rename(path)
    return path


def as_pinhole(path: Path) -> Path:
    """A view of the render at ``path`` whose rig.yaml leaves the lens out (the camera folders linked, not copied)."""
    out = path.with_name(path.name + "-as-pinhole")
    out.mkdir(exist_ok=True)
    for item in path.iterdir():
        if item.name != "rig.yaml" and not (out / item.name).exists():
            (out / item.name).symlink_to(item.resolve())
    rig = read_rig_yaml(path / "rig.yaml")
    write_rig_yaml(out / "rig.yaml", dataclasses.replace(rig, cameras=[dataclasses.replace(c, distortion=None)
                                                                        for c in rig.cameras]))  # fmt: skip
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_sequence_arguments(p, ["handheld-1007", "front-left-1008"])
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--workers", type=int, default=2, help="rendering processes")
    p.add_argument("--threads", type=int, default=2, help="torch's threads")
    p.add_argument("--out", default="bench/results/lens.json")
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    results = {}
    print(
        f"{'sequence':18} {'lens':18} {'rot':>6} {'dir':>6} {'t/b':>6} {'x pinhole (rot/dir/t)':>22} trusted  warnings"
    )
    for name in args.sequences:
        paths = {lens: render(Path(args.root), name, lens, args.frames, args.workers) for lens in LENSES}
        paths |= {f"{lens}-as-pinhole": as_pinhole(paths[lens]) for lens in LENSES if LENSES[lens] is not None}
        rows = results[name] = {}
        for lens, path in paths.items():
            r = run(path, "network", args.frames, BundleOptions(), None)
            row = rows[lens] = {key: r["bundle"][key] for key in KEYS} | {
                "trusted": r["trusted"], "warnings": r["warnings"]}  # fmt: skip
            base = rows["pinhole"]
            row["ratio_to_pinhole"] = [row[k] / base[k] if base[k] > 0 else None for k in KEYS]
            ratios = "/".join("n/a" if v is None else f"{v:.2f}" for v in row["ratio_to_pinhole"])
            print(f"{name:18} {lens:18} {row['rotation_deg']:6.2f} {row['direction_deg']:6.1f} "
                  f"{row['translation_rel_baseline']:6.2f} {ratios:>22} {str(row['trusted']):7}  "
                  f"{len(row['warnings'])}", flush=True)  # fmt: skip
        write_json(args.out, {"frames": args.frames, "lenses": {k: v and v.as_dict() for k, v in LENSES.items()},
                              "results": results})  # fmt: skip


if __name__ == "__main__":
    main()
