"""Diagnostic: where the on-line rig estimator's shared rotation about camera 0's x axis comes from, on the dev split's
cars (``bench_calibrate_split.py`` measures it: about +0.1 deg on every preset once the rig's poses are solved, about
0.005 with the trajectory held). Three measurements, each isolating one part:

- ``exact``: the estimator (``OnlineRigEstimator``, default options, the trajectory's 5 cm priors, started at the
  true rotations as every part is: a diagnostic of the component) fed exact
  projections of the render's own surfaces instead of SIFT features: points back-projected from the depth maps,
  observed where the depth map shows them, with Gaussian pixel noise and ideal descriptors. What remains is the
  estimator's process (keyframes, resection, triangulation, the window, its priors); the rotation errors per axis of
  camera 0's frame at the end.
- ``reversed``: the images themselves, the camera order reversed (the side camera the reference) and the trajectory
  held exact: the front camera's pitch then comes from its own images alone; its rotation error per axis of the
  front camera's frame.
- ``features``: SIFT matches two frames apart against the render's truth (the first keypoint back-projected through
  the depth map, projected into the second frame), the mean residual per band of image rows, per camera.

    python bench/bench_rig_pitch.py [--rigs front-left-6001 ...] [--parts exact reversed features]

Reads the rigs under ``--root`` (``bench_calibrate_split.py`` renders them). Writes ``bench/results/rig_pitch.json``.
Convention: rotation errors are ``innovation(estimate, truth)``'s rotation part, degrees, about camera 0's axes
(x right, y down, z forward).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from common import write_json

from ocalib.data.image_io import read_depth
from ocalib.data.layout import open_sequence
from ocalib.geometry.se3 import innovation
from ocalib.rigba.features import Features, SiftExtractor, match_features
from ocalib.rigba.online import OnlineRigEstimator, OnlineRigOptions

ROWS = 4  # bands of image rows the feature residuals are averaged over
PIXEL_NOISE = 0.3  # px, of the exact projections
SAMPLES = 300  # depth pixels back-projected per camera, every third frame


def trajectories(sequence) -> list[np.ndarray]:
    """Each camera's true camera-to-world poses (T, 4, 4), re-referenced to camera 0's first frame."""
    ref = np.linalg.inv(sequence.cameras[0].poses[0])
    return [ref @ np.asarray(cam.poses) for cam in sequence.cameras]


def depth_m(cam, t: int) -> np.ndarray:
    """Camera ``cam``'s depth map of frame t, metres (0: no surface)."""
    return read_depth(cam.depth[t], cam.depth_scale)[0].numpy().astype(np.float64)


class ExactObservations:
    """Exact projections of the render's surfaces as :class:`Features`: ``self(t, k)`` camera k's at frame t."""

    def __init__(self, sequence, poses: list[np.ndarray], seed: int = 0):
        self.sequence, self.poses, self.rng = sequence, poses, np.random.default_rng(seed)
        points = []
        for cam, P in zip(sequence.cameras, poses):
            h, w = cam.size
            for t in range(0, len(P), 3):
                d = depth_m(cam, t)
                v, u = self.rng.integers(0, h, SAMPLES), self.rng.integers(0, w, SAMPLES)
                z = d[v, u]
                ok = (z > 0) & (z < 100)
                rays = np.c_[u, v, np.ones(len(u))][ok] @ np.linalg.inv(cam.K).T
                points.append((rays * z[ok, None]) @ P[t][:3, :3].T + P[t][:3, 3])
        self.X = np.concatenate(points)
        self.descriptors = self.rng.normal(size=(len(self.X), 128)).astype(np.float32)
        self.descriptors /= np.linalg.norm(self.descriptors, axis=1, keepdims=True)
        self.priority = self.rng.permutation(len(self.X))

    def __call__(self, t: int, k: int) -> Features:
        cam = self.sequence.cameras[k]
        cam_from_world = np.linalg.inv(self.poses[k][t])
        p = self.X @ cam_from_world[:3, :3].T + cam_from_world[:3, 3]
        h, w = cam.size
        with np.errstate(all="ignore"):
            uv = p @ cam.K.T
            uv = uv[:, :2] / uv[:, 2:]
        seen = np.flatnonzero((p[:, 2] > 0.5) & (uv >= 0).all(1) & (uv[:, 0] <= w - 1) & (uv[:, 1] <= h - 1))
        d = depth_m(cam, t)[np.round(uv[seen, 1]).astype(int), np.round(uv[seen, 0]).astype(int)]
        seen = seen[np.abs(d - p[seen, 2]) < 0.03 * p[seen, 2] + 0.05]  # not hidden behind another surface
        seen = seen[np.argsort(self.priority[seen])][:1024]
        return Features(uv[seen] + self.rng.normal(0, PIXEL_NOISE, (len(seen), 2)), self.descriptors[seen])


def run_estimator(sequence, order: list[int], metric_noise, features=None) -> np.ndarray:
    """The estimator over the whole sequence with its cameras in ``order`` (the first the reference), started at the
    true rotations; ``features(t, k)`` replaces SIFT where given -> rotation errors (C - 1, 3) deg about the
    reference's axes."""
    cams = [sequence.cameras[k] for k in order]
    poses = [trajectories(sequence)[k] for k in order]
    truth = np.stack([np.linalg.inv(poses[0][0]) @ P[0] for P in poses])
    start = truth.copy()
    estimator = OnlineRigEstimator(
        np.stack([c.K for c in cams]), [tuple(c.size) for c in cams], start, OnlineRigOptions(metric_noise=metric_noise)
    )
    if features is not None:
        estimator.map.features = lambda t, k: features(t, order[k])
    for t in range(len(poses[0])):
        images = [t] * len(cams) if features is not None else [c.read_grey(t) for c in cams]
        estimator.update(t, images if estimator.keyframe_next else None, poses[0][t])
    return np.stack([np.degrees(innovation(estimator.extrinsics[k], truth[k])[:3]) for k in range(1, len(cams))])


def feature_residuals(sequence, k: int, frames: range) -> dict:
    """Camera k's SIFT matches from frame t to t + 2 against the truth: the mean residual (px, x and y), its
    standard error, and the median depth per band of image rows."""
    cam, P = sequence.cameras[k], trajectories(sequence)[k]
    h, w = cam.size
    sift = SiftExtractor()
    residuals, rows = [], []
    for t in frames:
        a, b = sift(cam.read_grey(t)), sift(cam.read_grey(t + 2))
        m = match_features(a.descriptors, b.descriptors)
        uv0, uv1 = a.keypoints[m[:, 0]], b.keypoints[m[:, 1]]
        d = depth_m(cam, t)
        iu = np.clip(np.round(uv0[:, 0]).astype(int), 1, w - 2)
        iv = np.clip(np.round(uv0[:, 1]).astype(int), 1, h - 2)
        z = d[iv, iu]
        patch = np.stack([d[iv + dy, iu + dx] for dy in (-1, 0, 1) for dx in (-1, 0, 1)], 1)
        smooth = (z > 0) & (z < 100) & (np.ptp(patch, 1) < 0.05 * z)  # off depth edges
        X = (np.c_[uv0, np.ones(len(uv0))] @ np.linalg.inv(cam.K).T) * z[:, None] @ P[t][:3, :3].T + P[t][:3, 3]
        cam_from_world = np.linalg.inv(P[t + 2])
        q = (X @ cam_from_world[:3, :3].T + cam_from_world[:3, 3]) @ cam.K.T
        r = uv1 - q[:, :2] / q[:, 2:]
        ok = smooth & (np.linalg.norm(r, axis=1) < 3)
        residuals.append(r[ok])
        rows.append(np.c_[uv0[ok, 1], z[ok]])
    r, yz = np.concatenate(residuals), np.concatenate(rows)
    bands = []
    for i in range(ROWS):
        s = (yz[:, 0] >= i * h / ROWS) & (yz[:, 0] < (i + 1) * h / ROWS)
        bands.append({"rows": [i * h // ROWS, (i + 1) * h // ROWS], "matches": int(s.sum()),
                      "mean_px": r[s].mean(0).tolist(), "se_px": (r[s].std(0) / np.sqrt(max(s.sum(), 1))).tolist(),
                      "median_depth_m": float(np.median(yz[s, 1]))})  # fmt: skip
    return {"camera": cam.name, "matches": len(r), "mean_px": r.mean(0).tolist(), "bands": bands}


def rotation_part(name: str, sequences: dict) -> dict:
    """Part ``exact`` or ``reversed`` on every rig of ``sequences`` (name -> Sequence): per rig its errors, and the
    mean and standard error per axis over the cameras."""
    rows = {}
    for rig, sequence in sequences.items():
        order = list(range(len(sequence.cameras)))
        if name == "exact":
            errors = run_estimator(sequence, order, 0.05, ExactObservations(sequence, trajectories(sequence)))
        else:
            R = np.linalg.inv(sequence.cameras[-1].T_cam0_cam)[:3, :3]  # camera 0 in the last camera's frame
            errors = run_estimator(sequence, order[::-1], None)[-1:] @ R  # about camera 0's own axes
        rows[rig] = errors.tolist()
        print(name, rig, np.round(errors, 3).tolist(), flush=True)
    a = np.concatenate([np.asarray(v) for v in rows.values()])
    summary = {"cameras": len(a), "mean_deg": a.mean(0).tolist(), "se_deg": (a.std(0) / np.sqrt(len(a))).tolist()}
    print(name, "mean deg", np.round(summary["mean_deg"], 3), "standard error", np.round(summary["se_deg"], 3))
    return {"rigs": rows, "summary": summary}


def features_part(sequence) -> dict:
    """Part ``features`` on one rig: :func:`feature_residuals` of each camera, frames 4 apart."""
    rows = {cam.name: feature_residuals(sequence, k, range(0, len(sequence) - 2, 4))
            for k, cam in enumerate(sequence.cameras)}  # fmt: skip
    for cam, row in rows.items():
        for band in row["bands"]:
            print("features", cam, "rows", band["rows"], band["matches"], "matches, mean px",
                  np.round(band["mean_px"], 3), "standard error", np.round(band["se_px"], 3))  # fmt: skip
    return {"rigs": rows}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--root", default="data/eval")
    p.add_argument("--rigs", nargs="+", default=[f"front-left-{6001 + i}" for i in range(5)])
    p.add_argument("--parts", nargs="+", choices=("exact", "reversed", "features"),
                   default=["exact", "reversed", "features"])  # fmt: skip
    p.add_argument("--out", default="bench/results/rig_pitch.json")
    args = p.parse_args()
    sequences = {name: open_sequence(Path(args.root) / name) for name in args.rigs}
    doc: dict = {"rigs": args.rigs, "pixel_noise_px": PIXEL_NOISE}
    for part in args.parts:
        doc[part] = features_part(sequences[args.rigs[0]]) if part == "features" else rotation_part(part, sequences)
    write_json(args.out, doc)


if __name__ == "__main__":
    main()
