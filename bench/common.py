"""What every benchmark records beside its numbers, and how it writes them.

Each ``bench/bench_*.py`` runs as a script (``python bench/bench_x.py``), so this module is imported as ``common``.
"""

from __future__ import annotations

import json
import os
import platform
from pathlib import Path

import cv2
import torch

ROOT = Path(__file__).resolve().parents[1]


def machine() -> dict:
    """The machine a result was measured on: CPUs, platform, Python, torch, OpenCV, the CUDA device, the load average."""
    return {
        "cpus": os.cpu_count(),
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "python": platform.python_version(),
        "torch": torch.__version__,
        "opencv": cv2.__version__,
        "cuda": torch.cuda.get_device_name() if torch.cuda.is_available() else None,
        "load_average": os.getloadavg(),
    }


def write_json(path: str | Path, doc: dict) -> Path:
    """Write ``doc`` with the :func:`machine` it ran on (key ``machine``) to ``path`` (folders made); say so."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc | {"machine": machine()}, indent=2) + "\n")
    print(f"wrote {path}")
    return path


def shown_path(path: str | Path) -> str:
    """``path`` as results record it: relative to the repository when inside it (``.`` for the repository itself),
    else the last part of its name, so that no machine's absolute paths are written."""
    path = Path(path).resolve()
    try:
        return path.relative_to(ROOT).as_posix()
    except ValueError:
        return path.name


def add_sequence_arguments(p, default: list[str]) -> None:
    """``--root`` and ``--sequences``: held-out rigs, rendered under the root when missing (``ensure`` of
    bench_calibnet_accuracy)."""
    p.add_argument("--root", default="data/eval", help="where held-out sequences live / are rendered")
    p.add_argument(
        "--sequences",
        nargs="+",
        default=default,
        help="sequence folders, or held-out names PRESET-SEED[-HxW] rendered under --root when missing",
    )
