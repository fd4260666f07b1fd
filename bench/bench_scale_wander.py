"""How consistent a front end's translation scale is, beside the lever-arm signal the rig's translation is solved from.

In a turn a camera off the rig's axis steps longer or shorter than camera 0: the translation of the extrinsic is
solved from that (and from the steps' directions). A front end whose scale wanders from frame to frame, differently
in each camera, hides it. For each held-out sequence (rendered when missing, as in ``bench_calibnet_accuracy.py``)
this runs ``calibrate`` with the front end's own scale (``--scale head``: no normalisation; OpenCV VO's is its own) and, per frame t and
camera k, the log ratio of the front end's step length to the true one, ``e_k(t)``. Over 25-frame windows (a turn):

- *wander*: std of the windowed mean of ``e_1 - e_0`` (the scale of camera 1 against camera 0);
- *signal*: std of the windowed mean of ``log(|t_1| / |t_0|)`` of the true steps (the lever arm);
- *jitter*: std of ``e_k(t) - e_k(t-1)`` per camera (frame to frame).

Frames whose true step is under 0.3x the camera's median are left out. Prints a table, writes JSON.

    python bench/bench_scale_wander.py [--sequences NAME ...] [--frames 300] [--frontend network|opencv]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from bench_calibnet_accuracy import DEFAULT, ensure
from common import write_json
from ocalib.calibnet.run import calibrate_sequence
from ocalib.data.layout import open_sequence

WINDOW = 25


def log_step_ratio(poses: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """poses, truth (T, C, 4, 4) camera-to-first-frame -> (e (T-1, C) log length ratio to the truth, the true step
    lengths (T-1, C), the kept frames (T-1,) bool)."""
    step = lambda P: np.linalg.norm((np.linalg.inv(P[:-1]) @ P[1:])[..., :3, 3], axis=-1)
    estimate, true = step(poses), step(truth)
    kept = (true > 0.3 * np.median(true, 0)).all(1) & (estimate > 0).all(1)
    return np.log(np.where(kept[:, None], estimate / np.where(true > 0, true, 1), 1)), true, kept


def windowed_std(x: np.ndarray) -> float:
    """Std of the WINDOW-frame moving mean of ``x`` (mean removed)."""
    return float(np.convolve(x - x.mean(), np.ones(WINDOW) / WINDOW, mode="valid").std())


def measure(path: Path, frames: int, frontend: str, checkpoint: str | None) -> dict:
    out = calibrate_sequence(path, frontend=frontend, checkpoint=checkpoint, scale="head", max_frames=frames,
                             progress=False)
    sequence = open_sequence(path)
    truth = np.stack([c.poses[:frames] for c in sequence.cameras], 1)
    truth = np.linalg.inv(truth[:1]) @ truth
    e, true, kept = log_step_ratio(out.run.rig.poses, truth)
    e, true = e[kept], true[kept]
    return {"wander": windowed_std(e[:, 1] - e[:, 0]), "signal": windowed_std(np.log(true[:, 1] / true[:, 0])),
            "jitter": [float(np.diff(e[:, k]).std()) for k in range(e.shape[1])], "frames": int(kept.sum())}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--root", default="data/eval", help="where held-out sequences live / are rendered")
    p.add_argument("--sequences", nargs="+", default=DEFAULT)
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--frontend", default="network", choices=("network", "opencv"))
    p.add_argument("--checkpoint")
    p.add_argument("--out", default="bench/results/scale_wander.json")
    args = p.parse_args()
    results = {}
    print(f"{'sequence':18} {'wander':>7} {'signal':>7} {'ratio':>6} {'jitter cam0 / cam1':>19}", flush=True)
    for name in args.sequences:
        path = ensure(Path(args.root), name, args.frames)
        r = results[path.name] = measure(path, args.frames, args.frontend, args.checkpoint)
        print(f"{path.name:18} {r['wander']:7.3f} {r['signal']:7.3f} {r['wander'] / r['signal']:6.1f} "
              f"{r['jitter'][0]:9.3f} / {r['jitter'][1]:.3f}", flush=True)
    write_json(args.out, {"frames": args.frames, "frontend": args.frontend, "window": WINDOW,
                          "checkpoint": args.checkpoint or "default", "results": results})


if __name__ == "__main__":
    main()
