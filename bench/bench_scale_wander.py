"""How consistent a front end's translation scale is, beside the lever-arm signal the rig's translation is solved from.

In a turn a camera off the rig's axis steps longer or shorter than camera 0: the translation of the extrinsic is
solved from that (and from the steps' directions). A front end whose scale wanders from frame to frame, differently
in each camera, hides it. For each held-out sequence (rendered when missing, as in ``bench_calibnet_accuracy.py``)
this runs ``calibrate`` with the front end's own scale (``--scale head``: no normalisation; OpenCV VO's is its
own) and, per frame t and camera k, the log ratio of the front end's step length to the true one, ``e_k(t)``. Over
25-frame windows (a turn; :func:`ocalib.eval.calibration_metrics.scale_wander`):

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

from ocalib.calibnet.run import calibrate_images
from ocalib.data.layout import open_sequence
from ocalib.eval.calibration_metrics import WANDER_WINDOW, scale_wander, step_length_errors
from ocalib.frontend import FRONTENDS, FrontEndOptions


def measure(path: Path, frames: int, frontend: str, checkpoint: str | None) -> dict:
    options = FrontEndOptions(frontend, checkpoint if frontend == "network" else None, scale="head")
    out = calibrate_images(path, frontend=options, max_frames=frames, progress=False)
    sequence = open_sequence(path)
    truth = np.stack([c.poses[:frames] for c in sequence.cameras], 1)
    truth = np.linalg.inv(truth[:1]) @ truth
    wander, signal = scale_wander(out.run.rig.poses, truth)
    e, _ = step_length_errors(out.run.rig.poses, truth)
    return {"wander": wander, "signal": signal, "jitter": np.diff(e, axis=0).std(0).tolist(), "frames": len(e)}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--root", default="data/eval", help="where held-out sequences live / are rendered")
    p.add_argument("--sequences", nargs="+", default=DEFAULT)
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--frontend", default="network", choices=FRONTENDS)
    p.add_argument("--checkpoint")
    p.add_argument("--out", default="bench/results/scale_wander.json")
    args = p.parse_args()
    results = {}
    print(f"{'sequence':18} {'wander':>7} {'signal':>7} {'ratio':>6} {'jitter cam0 / cam1':>19}", flush=True)
    for name in args.sequences:
        path = ensure(Path(args.root), name, args.frames)
        r = results[path.name] = measure(path, args.frames, args.frontend, args.checkpoint)
        print(
            f"{path.name:18} {r['wander']:7.3f} {r['signal']:7.3f} {r['wander'] / r['signal']:6.1f} "
            f"{r['jitter'][0]:9.3f} / {r['jitter'][1]:.3f}",
            flush=True,
        )
    write_json(
        args.out,
        {
            "frames": args.frames,
            "frontend": args.frontend,
            "window": WANDER_WINDOW,
            "checkpoint": args.checkpoint or "default",
            "results": results,
        },
    )


if __name__ == "__main__":
    main()
