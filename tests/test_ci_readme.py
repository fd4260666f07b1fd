"""CI's check of the demo's figures (``.ci/readme.py``): within the README's tolerances it passes, outside them,
with a NaN, or without the line it fails; the README's quoted lines are what it can check; the README installs with
constraints.txt, which pins every dependency within pyproject's bounds."""

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("ci_readme", ROOT / ".ci" / "readme.py")
readme = importlib.util.module_from_spec(spec)
spec.loader.exec_module(readme)

QUOTED = "cam1: rotation 0.077±0.05 deg, direction * deg, scaled x0.112±5%, error ≤20% of the baseline, cam 2"


@pytest.mark.parametrize(
    "printed, ok",
    [
        ("cam1: rotation 0.077 deg, direction 18.19 deg, scaled x0.112, error 15.3% of the baseline, cam 2", True),
        ("cam1: rotation 0.126 deg, direction 99.99 deg, scaled x0.1175, error 20.0% of the baseline, cam 2", True),
        ("  cam1:  rotation 0.028 deg, direction 0.00 deg, scaled x0.1065, error 0.0% of the baseline,  cam 2", True),
        ("cam1: rotation 0.128 deg, direction 18.19 deg, scaled x0.112, error 15.3% of the baseline, cam 2", False),
        ("cam1: rotation 0.077 deg, direction 18.19 deg, scaled x0.118, error 15.3% of the baseline, cam 2", False),
        ("cam1: rotation 0.077 deg, direction 18.19 deg, scaled x0.112, error 20.1% of the baseline, cam 2", False),
        ("cam1: rotation 0.077 deg, direction nan deg, scaled x0.112, error 15.3% of the baseline, cam 2", False),
        ("cam1: rotation 0.077 deg, direction 18.19 deg, scaled x0.112, error 15.3% of the baseline, cam 3", False),
        ("cam1: rotation 0.077 deg, direction 18.19 deg, scaled x0.112, error 15.3% of the baseline", False),
        (
            "cam1: rotation 0.077 deg, direction 1.9 deg (in the plane), scaled x0.112, error 3% of the baseline, cam 2",
            True,
        ),
        (
            "cam1: rotation 0.077 deg, direction 1.9 deg in the plane, scaled x0.112, error 3% of the baseline, cam 2",
            False,
        ),
    ],
)
def test_a_figure_passes_within_its_tolerance_and_fails_outside(printed, ok):
    problems = readme.demo_problems([QUOTED], ["a line before", printed, "a line after"])
    assert (problems == []) == ok, problems


def test_quoted_lines_are_found_in_their_order():
    """A quoted line is held by the printed line after the previous quoted one's, not by a like line before it."""
    quoted = ["estimator:", "cam1: error ≤10 deg", "adjustment:", "cam1: error ≤20 deg"]
    assert readme.demo_problems(quoted, ["estimator:", "cam1: error 5 deg", "adjustment:", "cam1: error 15 deg"]) == []
    swapped = readme.demo_problems(quoted, ["adjustment:", "cam1: error 15 deg", "estimator:", "cam1: error 5 deg"])
    assert swapped == ["not printed: adjustment:", "not printed: cam1: error ≤20 deg"]
    late = readme.demo_problems(quoted, ["cam1: error 5 deg", "estimator:", "cam1: error 15 deg", "adjustment:"])
    assert late[0] == "15 where the README allows ≤10: cam1: error 15 deg"


def test_the_readme_quotes_demo_lines_with_tolerances():
    figures = [spec for line in readme.block("demo output") for spec, _ in readme.line_check(line)[1]]
    assert len([spec for spec in figures if spec != "*"]) >= 6, figures


def test_the_readme_installs_with_the_constraints_and_they_pin_every_dependency_within_pyproject():
    import tomllib
    from packaging.requirements import Requirement
    from packaging.utils import canonicalize_name

    assert readme.block("install")[1:] == ['pip install -e ".[dev,docs]" -c constraints.txt']
    pins = {}
    for line in (ROOT / "constraints.txt").read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            name, version = line.split("==")
            pins[canonicalize_name(name)] = version
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras = project["optional-dependencies"]
    for spec in project["dependencies"] + extras["dev"] + extras["docs"]:
        requirement = Requirement(spec)
        pinned = pins.get(canonicalize_name(requirement.name))
        assert pinned is not None, f"{requirement.name} is not pinned in constraints.txt"
        assert requirement.specifier.contains(pinned, prereleases=True), f"{requirement.name}=={pinned} vs {spec}"
