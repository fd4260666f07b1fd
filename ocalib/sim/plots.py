"""Figures of the simulation, like the paper's Figure 2: error over iterations, one curve per noise level.

Convention: curves are medians over seeds of :class:`ocalib.sim.experiment.SimulationResult` errors.
"""

from __future__ import annotations

from pathlib import Path

from ocalib.sim.experiment import ERROR_LABELS, ERRORS, SimulationResult
from ocalib.viz.figure import save_figure


def plot_errors(result: SimulationResult, path: str | Path, methods: list[str] | None = None) -> Path:
    """One row per method, one panel per error kind (log scale, floored at 1e-6), one curve per noise level;
    saves a PNG. Frame 0 (no motion yet) is left out."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    methods = methods or list(result.errors)
    fig, axes = plt.subplots(
        len(methods), len(ERRORS), figsize=(3.2 * len(ERRORS), 2.6 * len(methods)), squeeze=False, sharex=True
    )
    colors = plt.cm.viridis_r([0.15 + 0.85 * i / max(len(result.noise) - 1, 1) for i in range(len(result.noise))])
    for row, method in zip(axes, methods):
        curves = result.curves(method).clamp_min(1e-6).numpy()  # (N, T, E); noise 0 sits on the floor
        for j, (ax, name) in enumerate(zip(row, ERRORS)):
            for i, sigma in enumerate(result.noise):
                ax.plot(range(1, result.frames), curves[i, 1:, j], color=colors[i], lw=1.2, label=f"noise {sigma:g}")
            ax.set_yscale("log")
            ax.grid(True, which="major", alpha=0.3)
            ax.set_title(f"{method}: {ERROR_LABELS[name]}" if j == 0 else ERROR_LABELS[name], fontsize=9)
    for ax in axes[-1]:
        ax.set_xlabel("iteration (frame)")
    axes[0, -1].legend(fontsize=7, loc="upper right")
    fig.suptitle(
        f"{result.trajectory} trajectory, {result.noise_model} noise, median of {result.seeds} seeds", fontsize=10
    )
    return save_figure(fig, path)
