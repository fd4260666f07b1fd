"""Per-frame calibration estimates as a figure: rotation, translation, scale and observability.

Convention: as :meth:`ocalib.calib.poses.pipeline.CalibrationRun.trace` -- arrays (F, K, n) over F frames and
K cameras; rotations are shown as the rotation from the final estimate to each frame's (or, given the
ground truth, from the true rotation to each frame's estimate: its error), about camera k's axes (the axes of
``rotation_std_deg``), in degrees.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from ocalib.geometry.angles import angles_text, rotation_error_deg
from ocalib.geometry.directions import angle_deg, touched_axes
from ocalib.geometry.quaternion import rotation_matrix_to_quaternion
from ocalib.viz.figure import save_figure

AXES = "xyz"
COLORS = ("tab:red", "tab:green", "tab:blue", "tab:gray")


def plot_trace(
    trace: dict[str, np.ndarray],
    cameras: list[str],
    path: str | Path,
    truth: np.ndarray | None = None,
    units: str | None = None,
    unobservable: list | None = None,
) -> None:
    """Write a PNG: one column per camera k, rows rotation / translation / scale / singular values / residuals, where
    the trace holds the on-line rig estimator's (``rig_*``, metres) a row of those, and where it holds the rig bundle
    adjustment's results (``bundle_*``, in ``units``) a row of those.

    truth: (K, 4, 4) the true ``T_cam0_camk``, or None. With it the rotation row shows each frame's error against
    the truth (with the reported 1-sigma band: an honest band covers zero about two times in three) and the
    translation row's title the angle between the final translation and the true one.

    unobservable: per camera k (as ``cameras``), the rig bundle adjustment's unobservable translation directions
    (n, 3) in camera 0's frame (:func:`bundle_unobservable` reads them from the result JSON), or None: marked on its
    row. Every panel's axis fits the settled estimate (the second half of the frames), not an early transient.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    frames, K = trace["frame"], trace["quaternion"].shape[1]
    bundle, rig = "bundle_translation" in trace, "rig_translation" in trace
    rows = 5 + rig + bundle
    fig, axes = plt.subplots(rows, K, figsize=(6.5 * K, 2.7 * rows), sharex=True, squeeze=False)
    for k in range(K):
        true_k = None if truth is None else truth[k]
        _rotation_row(axes[0, k], frames, trace, k, Path(cameras[k]).name, true_k)
        _translation_row(axes[1, k], frames, trace, k, true_k)
        s = trace["scale"][:, k]
        _bands(axes[2, k], frames, s, trace["scale_std"][:, k], [f"scale = {s[-1, 0]:.5f}"], min_span=1e-3)
        axes[2, k].set_title("scale (camera-k units -> camera-0 units)", fontsize=9)
        _observability_row(axes[3, k], frames, trace, k)
        _residual_row(axes[4, k], frames, trace, k)
        for frame in trace.get("change_frame", np.zeros((0, K)))[:, k]:  # the head's changes, at their first frame
            for ax in axes[:5, k] if np.isfinite(frame) else ():
                ax.axvline(frame, color="red", lw=1.5, ls=":", label="extrinsic changed")
        if rig:
            _rig_row(axes[5, k], frames, trace, k, true_k)
        if bundle:
            directions = None if unobservable is None else np.asarray(unobservable[k], dtype=float).reshape(-1, 3)
            _bundle_row(axes[5 + rig, k], frames, trace, k, true_k, units, directions)
    for ax in axes.flat:
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0] and ax.get_legend() is None:
            ax.legend(fontsize=8, loc="lower right" if ax.get_yscale() == "log" else "upper right")
        if ax.get_yscale() == "linear":
            ax.ticklabel_format(axis="y", useOffset=False)
    save_figure(fig, path, dpi=110)


def _rotation_row(ax, frames: np.ndarray, trace: dict, k: int, camera: str, truth: np.ndarray | None) -> None:
    """Camera k's rotation over the frames: its change against the final estimate, or its error against ``truth``
    (4, 4), with the reported 1-sigma band; flagged where the motion does not determine it."""
    q = trace["quaternion"][:, k]
    q_true = None if truth is None else rotation_matrix_to_quaternion(torch.from_numpy(truth[:3, :3])).numpy()
    if q_true is None:
        delta, what = rotation_error_deg(q, q[-1]), "rotation - final (deg)"
    else:
        delta = rotation_error_deg(q, q_true)
        what = f"rotation error against the truth (deg), final {np.linalg.norm(delta[-1]):.3f} deg"
    std = trace["rotation_std_deg"][:, k]
    unobservable = not trace["rotation_observable"][-1, k, 0] and not trace["planar_motion"][-1, k, 0]
    labels = [
        f"about {a}" + ("" if unobservable or not np.isfinite(sd) else f", std {sd:.2g}")
        for a, sd in zip(AXES, std[-1])
    ]
    _bands(ax, frames, delta, np.where(unobservable, np.inf, std), labels, min_span=0.02)
    title = f"{camera}: {what}\n{angles_text(q[-1])}"
    if q_true is not None:
        ax.axhline(0, color="black", lw=0.8, label="truth")
        title += f"\ntruth: {angles_text(q_true)}"
    ax.set_title(title, fontsize=9)
    if unobservable:
        ax.text(0.5, 0.5, "ROTATION UNOBSERVABLE\n(the motion does not determine it)", transform=ax.transAxes,
                ha="center", va="center", color="red", fontsize=11, alpha=0.8)  # fmt: skip


def _translation_row(ax, frames: np.ndarray, trace: dict, k: int, truth: np.ndarray | None) -> None:
    """Camera k's translation over the frames with its 1-sigma band; with ``truth`` (4, 4) the true direction at the
    final estimate's length (the units differ) and the final direction's error."""
    t, t_std = trace["translation"][:, k], trace["translation_std"][:, k]
    labels = [
        f"t{a} = {v:.4f}" + ("" if np.isfinite(sd) else " (unobservable)") for a, v, sd in zip(AXES, t[-1], t_std[-1])
    ]
    title = "translation in camera 0's frame (camera-0 units)"
    if truth is not None:
        true_t = truth[:3, 3]
        direction = true_t / max(np.linalg.norm(true_t), 1e-300)
        for i in range(3):
            ax.axhline(direction[i] * np.linalg.norm(t[-1]), color=COLORS[i], lw=1, ls="--")
        labels = [f"{label}, truth {v:+.4f}" for label, v in zip(labels, direction * np.linalg.norm(t[-1]))]
        title += (
            f"\ntruth (dashed): the true direction at the final length; final {angle_deg(t[-1], true_t):.1f} deg off"
        )
        include = direction * np.linalg.norm(t[-1])
    else:
        include = ()
    _bands(ax, frames, t, t_std, labels, min_span=1e-3 * max(np.abs(t[-1]).max(), 1e-3), include=include)
    ax.set_title(title, fontsize=9)


def _observability_row(ax, frames: np.ndarray, trace: dict, k: int) -> None:
    """The rotation system's singular values (log scale), the frames of unobservable or planar motion shaded."""
    sv = trace["rotation_singular_values"][:, k]
    for i in range(4):
        ax.plot(frames, np.maximum(sv[:, i], 1e-12), color=COLORS[i], lw=1, label=f"S{i}")
    ax.set_yscale("log")
    tail = sv[len(sv) // 10 :]
    ax.set_ylim(max(tail[tail > 0].min(initial=1.0) / 3, 1e-9), tail.max(initial=1.0) * 3)
    planar = trace["planar_motion"][:, k, 0] == 1
    for flag, color, label in (
        ((trace["rotation_observable"][:, k, 0] == 0) & ~planar, "red", "rotation unobservable"),
        (planar, "orange", "planar motion (rotation from translation)"),
    ):
        if flag.any():
            ax.fill_between(frames, 0, 1, where=flag, transform=ax.get_xaxis_transform(), color=color,
                            alpha=0.15, step="mid", label=label)  # fmt: skip
    more = f" (first 4 of {sv.shape[-1]})" if sv.shape[-1] > 4 else ""  # absolute poses: 9
    ax.set_title(f"observability: rotation singular values{more}", fontsize=9)


def _residual_row(ax, frames: np.ndarray, trace: dict, k: int) -> None:
    """The fit's RMS residuals so far: rotation (deg) and translation (% of camera 0's motion)."""
    if "rotation_residual_deg" in trace:
        residuals = trace["rotation_residual_deg"][:, k, 0], 100 * trace["translation_residual"][:, k, 0]
        ax.plot(frames, residuals[0], color=COLORS[0], lw=1, label="rotation (deg)")
        ax.plot(frames, residuals[1], color=COLORS[2], lw=1, label="translation (% of camera 0's motion)")
        if any((r[np.isfinite(r)] > 0).any() for r in residuals):
            ax.set_yscale("log")
    ax.set_title("fit residuals, RMS over the motion pairs (absolute poses: frames) so far", fontsize=9)
    ax.set_xlabel("frame")


def _rig_row(ax, frames: np.ndarray, trace: dict, k: int, truth: np.ndarray | None) -> None:
    """The on-line rig estimator's translation (metres) over the frames with its 1-sigma band, the truth at frame 0
    dashed, and the changes it noticed as vertical lines at the first frame that disagreed."""
    t, t_std = trace["rig_translation"][:, k], trace["rig_translation_std"][:, k]
    started = np.isfinite(t[:, 0])
    title = "on-line rig estimator: translation (m)"
    if not started.any():
        ax.text(0.5, 0.5, "not started (see the warnings)", transform=ax.transAxes, ha="center", color="red")
        ax.set_title(title, fontsize=9)
        return
    labels = [f"t{a} = {v:+.4f}" + ("" if np.isfinite(sd) else " (unobservable)") for a, v, sd in
              zip(AXES, t[started][-1], t_std[started][-1])]  # fmt: skip
    if truth is not None:
        for i in range(3):
            ax.axhline(truth[i, 3], color=COLORS[i], lw=1, ls="--")
        labels = [f"{label}, truth {v:+.4f}" for label, v in zip(labels, truth[:3, 3])]
        title += ", truth at frame 0 dashed"
    include = () if truth is None else truth[:3, 3]
    _bands(ax, frames[started], t[started], t_std[started], labels, min_span=0.05, include=include)
    for frame in trace.get("rig_change_frame", np.zeros((0, 0)))[:, k]:
        if np.isfinite(frame):
            ax.axvline(frame, color="red", lw=1.5, ls=":")
    ax.set_title(title, fontsize=9)


def _bundle_row(
    ax,
    frames: np.ndarray,
    trace: dict,
    k: int,
    truth: np.ndarray | None,
    units: str | None,
    unobservable: np.ndarray | None = None,
) -> None:
    """The rig bundle adjustment's translation at the frames where it ran (markers), the truth dashed (when in
    metres), and its rotation's error against the truth in the title. Its ``unobservable`` translation directions
    (n, 3) are named in the panel, and the axes they have a share in (:func:`~ocalib.geometry.directions.touched_axes`, as the
    result's 1-sigma counts them) are labelled unobservable and drawn faint: their values are not measurements."""
    t, q = trace["bundle_translation"][:, k], trace["bundle_quaternion"][:, k]
    ran = np.isfinite(t[:, 0])
    title = f"rig bundle adjustment: translation ({units or 'its units'})"
    metric_truth = truth is not None and units == "metres"
    unobservable = np.zeros((0, 3)) if unobservable is None else unobservable
    loose = touched_axes(unobservable)
    for i in range(3):
        label = (
            f"t{AXES[i]}" + (f" = {t[ran][-1, i]:+.4f}" if ran.any() else "") + (" (unobservable)" if loose[i] else "")
        )
        ax.plot(
            frames[ran],
            t[ran, i],
            marker="o",
            color=COLORS[i],
            lw=1,
            ls=":" if loose[i] else "-",
            alpha=0.4 if loose[i] else 1.0,
            label=label + (f", truth {truth[i, 3]:+.4f}" if metric_truth else ""),
        )
        if metric_truth:
            ax.axhline(truth[i, 3], color=COLORS[i], lw=1, ls="--")
    if ran.any():
        scale = max(np.abs(t[ran]).max(), 1e-3)
        _settled_limits(ax, t[ran], min_span=0.2 * scale, include=truth[:3, 3] if metric_truth else ())
    if len(unobservable) and ran.any():
        ax.text(0.99, 0.03, "unobservable along " + ", ".join("[" + ", ".join(f"{v:+.2f}" for v in d) + "]"
                for d in unobservable) + " (camera 0's frame): not a measurement there", transform=ax.transAxes,
                ha="right", va="bottom", color="red", fontsize=8)  # fmt: skip
    if truth is not None and ran.any():
        q_true = rotation_matrix_to_quaternion(torch.from_numpy(truth[:3, :3])).numpy()
        error = np.linalg.norm(rotation_error_deg(q[ran][-1:], q_true)[-1])
        title += f"; rotation {error:.3f} deg off the truth" + (", truth dashed" if metric_truth else "")
    if not ran.any():
        ax.text(
            0.5,
            0.5,
            "not trusted: the on-line estimate is kept (see the warnings)",
            transform=ax.transAxes,
            ha="center",
            va="center",
            color="red",
            fontsize=10,
        )
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("frame")
    ax.legend(fontsize=8, loc="upper left")


def _bands(
    ax, x: np.ndarray, y: np.ndarray, std: np.ndarray, labels: list[str], min_span: float = 0.0, include=()
) -> None:
    """Lines y (F, n) with +-1 sigma bands (infinite sigma: no band), the axis scaled to the settled estimate (see
    :func:`_settled_limits`; ``include``: values to keep in view too, such as the truth)."""
    for i, label in enumerate(labels):
        color = COLORS[i] if y.shape[1] > 1 else "black"
        ax.plot(x, y[:, i], color=color, lw=1, label=label)
        s = np.where(np.isfinite(std[:, i]), std[:, i], np.nan)
        ax.fill_between(x, y[:, i] - s, y[:, i] + s, color=color, alpha=0.2, lw=0)
    _settled_limits(ax, y, std, min_span, include)


def _settled_limits(ax, y: np.ndarray, std: np.ndarray | None = None, min_span: float = 0.0, include=()) -> None:
    """Y-limits from the second half of the frames' values y (F, n) with their finite 1-sigma ``std`` and the
    ``include`` values, with a margin, at least ``min_span`` apart (so that a constant line is not drawn on an axis
    of 1e-7 steps): an early transient does not hide the final values. Where earlier values leave the axis, a note
    says so."""
    settled = y[len(y) // 2 :]
    s = np.zeros_like(settled) if std is None else np.where(np.isfinite(std[len(y) // 2 :]), std[len(y) // 2 :], 0.0)
    extra = np.asarray(include, dtype=float).ravel()
    with np.errstate(invalid="ignore"):
        lo = np.nanmin(np.r_[(settled - s).ravel(), extra], initial=np.inf)
        hi = np.nanmax(np.r_[(settled + s).ravel(), extra], initial=-np.inf)
    if not (np.isfinite(lo) and np.isfinite(hi)):
        return
    if hi - lo < min_span:
        lo, hi = (lo + hi - min_span) / 2, (lo + hi + min_span) / 2
    pad = max(hi - lo, 1e-6 * max(abs(lo), abs(hi), 1.0)) * 0.15
    lo, hi = lo - pad, hi + pad
    ax.set_ylim(lo, hi)
    early = y[: len(y) // 2]
    if ((early < lo) | (early > hi)).any():
        ax.text(0.01, 0.97, "axis fits the second half; earlier values run off it", transform=ax.transAxes,
                ha="left", va="top", fontsize=7, color="dimgray")  # fmt: skip


def bundle_unobservable(doc: dict) -> list[list]:
    """Per camera k >= 1 of a result JSON, the rig bundle adjustment's unobservable translation directions (n, 3)
    where its extrinsic is the result (``"source": "bundle_adjustment"``), else none: ``plot_trace``'s
    ``unobservable``."""
    return [
        e["observability"].get("unobservable_translation_directions", [])
        if e.get("source") == "bundle_adjustment"
        else []
        for e in doc["extrinsics"]
    ]
