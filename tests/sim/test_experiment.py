"""The paper's simulation (ocalib.sim.experiment) and ``ocalib simulate``."""

from __future__ import annotations

import argparse
import json

import pytest

from ocalib.cli import simulate as cli
from ocalib.errors import InputError
from ocalib.sim.experiment import ERRORS, method_kwargs, simulate


def test_noise_free_default_is_exact():
    result = simulate([0.0], seeds=3, frames=24, methods=["default"])
    final = result.errors["default"][:, :, -1]
    assert final.isfinite().all()
    assert final.max() < 1e-6


@pytest.mark.parametrize("noise_model", ["independent", "drift"])
def test_errors_grow_with_noise(noise_model):
    result = simulate([0.001, 0.01, 0.05], seeds=5, frames=40, noise_model=noise_model, methods=["default"])
    summary = result.summary()["final"]["default"]
    for name in ("rotation_deg", "translation_rel"):
        medians = [summary[s][name]["median"] for s in ("0.001", "0.01", "0.05")]
        assert medians[0] < medians[1] < medians[2], (name, medians)


def test_method_names():
    assert method_kwargs("gaps-1-2-4-8") == {"motion": (1, 2, 4, 8)}
    assert method_kwargs("paper-rls-delay")["rls_delay"] == 60
    with pytest.raises(InputError):
        method_kwargs("gaps-a")


def _args(tmp_path, **overrides):
    parser = argparse.ArgumentParser()
    cli.add_parser(parser.add_subparsers(), "simulate")
    argv = [
        "simulate",
        "--noise",
        "0,0.01",
        "--seeds",
        "2",
        "--frames",
        "12",
        "--methods",
        "paper-rls,default",
        "--out",
        str(tmp_path / "out"),
        "--tensorboard",
        str(tmp_path / "tb"),
    ]
    for key, value in overrides.items():
        argv += [f"--{key}", str(value)]
    return parser.parse_args(argv)


def test_cli_end_to_end(tmp_path):
    assert cli.run(_args(tmp_path, trajectory="car")) == 0
    summary = json.loads((tmp_path / "out/summary.json").read_text())
    assert set(summary["final"]) == {"paper-rls", "default"}
    assert set(summary["final"]["default"]["0.01"]) == set(ERRORS)
    assert (tmp_path / "out/simulation.png").stat().st_size > 0
    assert (tmp_path / "out/simulation_default.png").exists()
    assert any((tmp_path / "tb").iterdir())


@pytest.mark.parametrize("bad", [{"noise": "-0.1"}, {"noise": "abc"}, {"frames": 0}, {"seeds": 0}, {"methods": "nope"}])
def test_bad_input(tmp_path, bad):
    with pytest.raises(InputError):
        cli.run(_args(tmp_path, **bad))
