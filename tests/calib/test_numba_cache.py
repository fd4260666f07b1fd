"""The compiled kernels' on-disk cache: a later process loads what an earlier one compiled, and an edit of any kernel
module or of the PyTorch module beside one never runs stale compiled code."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("numba", reason="numba is not installed")

ROOT = Path(__file__).resolve().parents[2]

# A kernel in rotation_kernel.py that calls a twin of linalg_kernel.py and reads a constant of rotation.py: numba's
# own check, the compiled function's file alone, would keep it after an edit of either of those files.
PROBE = """
from ocalib.calib.stages.linalg_kernel import left_product_matrix
from ocalib.calib.stages.rotation import ROTATION_OBSERVABLE_SIGNIFICANCE


@jit
def probe(q, L):
    left_product_matrix(q, L)
    return L[0, 0] + ROTATION_OBSERVABLE_SIGNIFICANCE
"""
RUN = """
import json
import numpy as np
from ocalib.calib.stages import rotation_kernel
value = rotation_kernel.probe(np.array([1.0, 0.0, 0.0, 0.0]), np.empty((4, 4)))
stats = rotation_kernel.probe.stats
print(json.dumps({"value": value, "hits": sum(stats.cache_hits.values()), "file": rotation_kernel.__file__}))
"""


def run(tree: Path, **env) -> dict:
    """The probe's value and numba's cache hits in a new process importing ``tree``'s package."""
    environ = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"} | {"PYTHONPATH": str(tree)} | env
    out = subprocess.run([sys.executable, "-c", RUN], env=environ, cwd=tree, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    doc = json.loads(out.stdout.splitlines()[-1])
    assert Path(doc["file"]).is_relative_to(tree)
    return doc


def edit(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text, f"{path.name} no longer holds {old!r}"
    path.write_text(text.replace(old, new))


def twice(tree: Path) -> tuple:
    """The probe's value and cache hits in two processes, one after the other."""
    first, second = run(tree), run(tree)
    return first["value"], first["hits"], second["value"], second["hits"]


def test_a_cached_kernel_is_loaded_and_never_stale_after_an_edit(tmp_path):
    shutil.copytree(ROOT / "ocalib", tmp_path / "ocalib", ignore=shutil.ignore_patterns("__pycache__", "*.pt"))
    calib = tmp_path / "ocalib" / "calib" / "stages"
    with (calib / "rotation_kernel.py").open("a") as f:
        f.write(PROBE)
    assert twice(tmp_path) == (21.0, 0, 21.0, 1)  # compiled, then loaded

    edit(calib / "linalg_kernel.py", "= w, -x, -y, -z", "= 2.0 * w, -x, -y, -z")  # the twin it calls
    assert twice(tmp_path) == (22.0, 0, 22.0, 1)
    edit(calib / "rotation.py", "ROTATION_OBSERVABLE_SIGNIFICANCE = 20.0", "ROTATION_OBSERVABLE_SIGNIFICANCE = 30.0")
    edited = run(tmp_path)
    assert (edited["value"], edited["hits"]) == (32.0, 0)  # recompiled, not the stale one
    assert len(list((calib / "__pycache__").glob("numba-*"))) == 1  # the older digests' folders removed

    cache = tmp_path / "cache"  # NUMBA_CACHE_DIR, where set, holds it instead
    assert run(tmp_path, NUMBA_CACHE_DIR=str(cache))["hits"] == 0
    assert [p.name.startswith("ocalib-") for p in cache.iterdir()] == [True]
