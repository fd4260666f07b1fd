"""Figures of one camera's evaluation: trajectory top view, per-frame scale ratio, error histograms, the
predicted against the true rotation about each camera axis (the rotation gain) and the rotation error over time.

Convention: trajectories are drawn in the ground truth's first camera frame (x right, z forward), the
prediction after its Sim(3) alignment; the top view is the x-z plane.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ocalib.eval.evaluate import CameraEvaluation
from ocalib.eval.pose_metrics import frame_motions
from ocalib.geometry.se3 import so3_log
from ocalib.viz.figure import save_figure


def plot_camera(result: CameraEvaluation, path: str | Path, title: str = "") -> Path:
    """Write a PNG of 2x3 panels (those without data say so) and return its path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(17, 9))
    d = result.details
    ax = axes[0, 0]
    if d is not None:
        gt, pred = result.truth[:, :3, 3], d["aligned"][:, :3, 3]
        ax.plot(gt[:, 0], gt[:, 2], "k-", label="ground truth")
        ax.plot(pred[:, 0], pred[:, 2], "tab:red", label=f"predicted, Sim(3)-aligned (scale {d['sim3']['scale']:.3g})")
        ax.plot(gt[:1, 0], gt[:1, 2], "ko")
        ax.set_aspect("equal", adjustable="datalim")
        ax.legend(fontsize=8)
        ax.set_title(f"trajectory, top view (ATE {result.pose['ate_rmse']:.3g})", fontsize=10)
    else:
        pred = result.poses[:, :3, 3]
        ax.plot(pred[:, 0], pred[:, 2], "tab:red", label="predicted (network units)")
        ax.legend(fontsize=8)
        ax.set_title("trajectory, top view (no ground-truth poses)", fontsize=10)
    ax.set_xlabel("x")
    ax.set_ylabel("z")

    ax = axes[0, 1]
    if d is not None:
        frames = np.arange(1, len(d["scale_ratio"]) + 1)
        ratio = d["scale_ratio"]
        ax.plot(frames, ratio, ".-", ms=3)
        ax.axhline(np.nanmedian(ratio), color="k", lw=0.8, ls="--", label="median")
        ax.legend(fontsize=8)
        ax.set_title(f"per-frame scale |t_pred| / |t_gt| (CV {result.pose['scale_ratio_cv']:.3g})", fontsize=10)
        ax.set_xlabel("frame")
    else:
        _empty(ax, "no ground-truth poses")

    ax = axes[1, 0]
    if d is not None:
        rot, direction = d["rotation_deg"], d["direction_deg"][d["moving"]]
        bins = np.linspace(0, max(np.percentile(np.r_[rot, direction], 99), 1e-6), 40)
        ax.hist(
            np.clip(direction, None, bins[-1]),
            bins,
            alpha=0.6,
            label=f"translation direction (median {np.median(direction):.3g})",
        )
        ax.hist(np.clip(rot, None, bins[-1]), bins, alpha=0.6, label=f"rotation (median {np.median(rot):.3g})")
        ax.legend(fontsize=8)
        ax.set_title("frame-to-frame errors (deg)", fontsize=10)
    else:
        _empty(ax, "no ground-truth poses")

    ax = axes[1, 1]
    abs_rel = [m["abs_rel"] for m in result.per_image if m is not None]
    if abs_rel:
        ax.hist(abs_rel, 30)
        ax.set_title(f"depth abs rel per image (mean {np.mean(abs_rel):.3g})", fontsize=10)
    else:
        _empty(ax, "no ground-truth depth")
    ax = axes[0, 2]
    if d is not None:
        pred, true = (np.degrees(so3_log(frame_motions(p)[:, :3, :3])) for p in (result.poses, result.truth))
        gains = result.pose["rotation_gain_xyz"]
        for i, (axis, colour) in enumerate(zip("xyz", ("tab:red", "tab:green", "tab:blue"))):
            gain = "n/a" if gains[i] is None or not np.isfinite(gains[i]) else f"{gains[i]:.2f}"
            ax.plot(true[:, i], pred[:, i], ".", ms=3, color=colour, label=f"about {axis} (gain {gain})")
        lim = max(np.abs(true).max(), np.abs(pred).max(), 1e-6)
        ax.plot([-lim, lim], [-lim, lim], "k-", lw=0.8, label="unbiased")
        ax.set_aspect("equal")
        ax.legend(fontsize=8)
        ax.set_title("frame-to-frame rotation vector, predicted vs true (deg)", fontsize=10)
        ax.set_xlabel("true")
        ax.set_ylabel("predicted")

        ax = axes[1, 2]
        ax.plot(np.arange(1, len(d["rotation_deg"]) + 1), d["rotation_deg"], ".-", ms=3)
        ax.set_title("frame-to-frame rotation error (deg)", fontsize=10)
        ax.set_xlabel("frame")
    else:
        _empty(axes[0, 2], "no ground-truth poses")
        _empty(axes[1, 2], "no ground-truth poses")
    fig.suptitle(f"{title} camera {result.name}".strip(), fontsize=11)
    return save_figure(fig, path)


def _empty(ax, text: str) -> None:
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes)
    ax.set_axis_off()
