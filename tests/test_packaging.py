"""The installed package: every source folder is packaged, and the training application cannot be hidden by a
user's ``train.py``."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _pyproject() -> dict:
    tomllib = pytest.importorskip("tomllib")
    return tomllib.loads((ROOT / "pyproject.toml").read_text())


def test_every_source_folder_is_a_listed_package():
    setuptools = _pyproject()["tool"]["setuptools"]
    listed = set(setuptools["packages"])
    mapping = setuptools["package-dir"]
    on_disk = set()
    for folder in [ROOT / "ocalib", *(ROOT / "ocalib").rglob("*")]:
        if (
            folder.is_dir()
            and folder.name != "__pycache__"
            and any(f.suffix in (".py", ".pt") for f in folder.iterdir())
        ):
            on_disk.add(".".join(folder.relative_to(ROOT).parts))
    for name, folder in mapping.items():
        assert (ROOT / folder / "__init__.py").is_file(), f"{name} maps to {folder}, which is not a package"
        on_disk.add(name)
    assert listed == on_disk, f"unlisted: {sorted(on_disk - listed)}, listed but absent: {sorted(listed - on_disk)}"
    assert mapping == {"ocalib.train": "train"}


def test_train_runs_from_a_folder_holding_train_py(tmp_path):
    for name in ("train.py", "ocalib_train.py"):
        (tmp_path / name).write_text("raise SystemExit('the user file ran')\n")
    out = subprocess.run(
        [sys.executable, "-m", "ocalib", "train", "fit", "--help"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert "the user file ran" not in out.stdout + out.stderr
    assert "--model.align" in out.stdout  # the LightningCLI of ocalib.train answered
