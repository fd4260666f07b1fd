"""The figures the README and the pages of docs/ quote from benchmarks are what ``bench/results/*.json`` hold
(``.ci/readme.py``'s figure check): each declared figure rounds to its JSON value or lies within its stated
tolerance, and is quoted where declared; a perturbed figure, a figure the text does not quote, a missing key and a
value out of tolerance each fail."""

import importlib.util
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("ci_readme", ROOT / ".ci" / "readme.py")
readme = importlib.util.module_from_spec(spec)
spec.loader.exec_module(readme)


# the pages that quote figures, and how many each declares at least: a removed declaration, or a page whose
# figures moved without their check, shows here
DECLARED = {
    "docs/guide.md": 39,
    "docs/method.md": 28,
    "docs/results-rigba.md": 96,
    "docs/results-rig-online.md": 67,
    "docs/simulation.md": 17,
    "docs/results-calibrate.md": 3,
    "docs/benchmarks.md": 17,
    "docs/results-change.md": 54,
}


@pytest.mark.parametrize("page", readme.documents(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_declared_figure_of_a_page_holds(page):
    problems, checked = readme.figure_problems(page.read_text(), ROOT / "bench" / "results")
    assert problems == []
    assert checked >= DECLARED.get(str(page.relative_to(ROOT)), 0)


def test_the_pages_declare_their_figures():
    pages = {str(p.relative_to(ROOT)) for p in readme.documents()}
    assert set(DECLARED) <= pages
    total = sum(readme.figure_problems(p.read_text(), ROOT / "bench" / "results")[1] for p in readme.documents())
    assert total >= 260  # every figure the README declared before the pages took them over


@pytest.fixture
def results(tmp_path):
    """A results folder of two files: bench.json and other.json."""
    (tmp_path / "bench.json").write_text(
        json.dumps(
            {
                "summary": {"us": 48.36, "ms": 18.43},
                "rigs": {"a": {"deg": 0.077}, "b": {"deg": 1.858}, "c": {"deg": 0.43}, "d": {"deg": 25.8}},
                "runs": [{"fps": 14.97}, {"fps": 9.2}, {"fps": 30.1}],
            }
        )  # fmt: skip
    )
    (tmp_path / "other.json").write_text(json.dumps({"x": 0.10646}))
    return tmp_path


def _readme(text: str, lines: str) -> str:
    return f"Intro.\n\n{text}\n\n<!-- figures from bench/results/bench.json\n{lines}\n-->\n\nNext paragraph 9.99.\n"


@pytest.mark.parametrize(
    "text, lines, ok",
    [
        ("One frame takes 48 us, 4096 rigs 18.4 ms.", "48 = summary/us\n18.4 = summary/ms", True),
        ("One frame takes 49 us.", "49 = summary/us", False),  # perturbed by one in its last digit
        ("One frame takes 48.4 us.", "48.4 = summary/us", True),
        ("One frame takes 48.3 us.", "48.3 = summary/us", False),
        ("One frame takes 48 us.", "47 = summary/us", False),  # declared but not quoted
        ("Quoted 9.99 only below.", "9.99 = summary/us", False),  # the next paragraph does not count
        ("One frame takes 48 us.", "48 = summary/missing", False),
        ("About 14 frames a second.", "14 ±10% = runs/0/fps", True),
        ("About 13 frames a second.", "13 ±10% = runs/0/fps", False),  # 15 % off
        ("About 14 frames a second.", "14 ±1 = runs/0/fps", True),
        ("Absolute 0.106.", "0.106 = other.json/x", True),
        ("Absolute 0.107.", "0.107 = other.json/x", False),
        ("From 0.08 to 1.86, median 0.43.", "0.08 = min rigs/*/deg except d\n1.86 = max rigs/*/deg except d", True),
        ("Median 0.43.", "0.43 = median rigs/*/deg except d", True),  # of 0.077, 1.858, 0.43
        ("Median 0.43.", "0.43 = median rigs/*/deg", False),  # with d: (0.43 + 1.858) / 2
        ("At least 9.2 frames a second.", "9.2 = min runs/*/fps", True),  # a list's every index
        ("At least 15 frames a second.", "15 = min runs/*/fps except 1", True),
        ("At least 9.2 frames a second.", "9.2 = min runs/*/fps except 1", False),
        ("Up to 1.86.", "1.86 = rigs/*/deg", False),  # several values need min, max or median
        ("Up to 1.86.", "up to 1.86 here", False),  # not a figure line
    ],
)
def test_a_figure_holds_within_its_tolerance_and_fails_outside(results, text, lines, ok):
    problems, checked = readme.figure_problems(_readme(text, lines), results)
    assert (problems == []) == ok, problems
    assert checked == (len(lines.splitlines()) if "here" not in lines else 0)
