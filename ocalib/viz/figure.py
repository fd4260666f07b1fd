"""Writing a matplotlib figure to disk, the one way every ocalib plot does it."""

from __future__ import annotations

from pathlib import Path

from ocalib.errors import InputError


def save_figure(fig, path: str | Path, dpi: int = 90) -> Path:
    """Lay out ``fig``, write it to ``path`` (its folder made if missing), close it. -> the path."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    path = Path(path)
    if path.is_dir():
        plt.close(fig)
        raise InputError(f"{path}: a folder; give the image's file name")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path
