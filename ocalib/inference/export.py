"""Writing a model's predictions for a sequence to a folder (what ``ocalib predict`` makes).

```
OUT/<camera>/depth/000000.npy ...   # float32 (H, W) depth at the model's resolution, network units
OUT/<camera>/poses.txt              # KITTI: camera-to-first-frame, chained frame-to-frame motions
OUT/<camera>/K.txt                  # the 3x3 intrinsics of the depth maps (the model's view of the camera)
```

Convention: as :mod:`ocalib.inference.predict` (``P_t = P_{t-1} T_{t-1,t}``, frame 0 the identity).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ocalib.data.model_view import model_view
from ocalib.data.sequence import Sequence
from ocalib.geometry.se3 import chain_motions
from ocalib.inference.predict import PredictOptions, predict_frames
from ocalib.io.poses import write_kitti


def save_predictions(
    model, sequence: Sequence, out, device="cpu", options: PredictOptions = PredictOptions(), progress=False
) -> dict[str, np.ndarray]:
    """Predict every camera of ``sequence`` (:func:`~ocalib.inference.predict.predict_frames`) and write the folder
    ``out``; returns camera name -> poses (N, 4, 4)."""
    out, names, depth = Path(out), sequence.names, options.depth
    frames = predict_frames(model, sequence, device, options, progress)  # checks the input
    for cam in sequence.cameras:
        folder = out / cam.name
        (folder / "depth" if depth else folder).mkdir(parents=True, exist_ok=True)
        np.savetxt(folder / "K.txt", model_view(cam, model.height, model.width).K, fmt="%.9g")
    motions = []
    for frame in frames:
        motions.append(frame.motion)
        if depth:
            for name, d in zip(names, frame.depth):
                np.save(out / name / "depth" / f"{frame.frame:06d}.npy", d)
    motions = np.stack(motions, 1)  # (C, N, 4, 4)
    poses = {name: chain_motions(m[1:]) for name, m in zip(names, motions)}
    for name, P in poses.items():
        write_kitti(out / name / "poses.txt", P)
    return poses
