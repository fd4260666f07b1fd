"""The README's commands and figures that CI runs and checks.

    python .ci/readme.py install   the install commands, one a line, as CI runs them
    python .ci/readme.py test      the test command
    python .ci/readme.py demo OUT  check every line the README quotes from the demo against OUT (its stdout)
    python .ci/readme.py figures   check the figures that README.md and docs/**/*.md quote from benchmarks against
                                   bench/results/*.json

The README marks each block with a comment line before it: ``<!-- ci: install -->``, ``<!-- ci: test -->``,
``<!-- ci: demo output -->``. CI installs torch itself (the pinned version: here the CPU build; PyTorch's CPU
wheel index in the README's first line cannot be reached from CI's machine), so the README's torch line must be
exactly TORCH_LINE and is left out of what ``install`` prints.

A quoted demo line is matched against the printed lines figure by figure: ``0.077±0.05`` is a figure within 0.05 of
0.077, ``0.112±5%`` one within 5 % of 0.112, ``≤20`` one at most 20, ``*`` any figure (not checked: it is
ill-conditioned); every other character must be as printed, but for a parenthesised note the printed line carries
and the quote leaves out. A figure is digits, so a printed ``nan`` never matches. The quoted lines are found in the
printed ones in their order.

A figure the README or a page of docs/ quotes from a benchmark is declared in a comment after the paragraph or
table that quotes it, one figure a line (tests/test_readme_figures.py runs the check on every such page)::

    <!-- figures from bench/results/online.json
    48 = summary/one_rig_us
    14 ±10% = calibnet.json/runs/0/cases/aligned graph/fps
    0.43 = median results/*/network (normalise), aligned/rotation_deg except front-left-1006
    -->

The figure must appear in that paragraph or table; the value at the key path (``/`` between keys, a list's index
as a number; a first part ending in ``.json`` names another file in the same folder) must round to it (within half a
unit of its last digit), or lie within the stated ``±`` tolerance (absolute, or ``%`` of the figure). ``min``,
``max`` and ``median`` take the values of every key (or list index) at a ``*`` (those after ``except``, separated by
``;``, left out).
"""

import json
import re
import statistics
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
TORCH_LINE = "pip install torch==2.13.0 --index-url https://download.pytorch.org/whl/cpu"


def block(name: str) -> list[str]:
    """The lines of the fenced block after ``<!-- ci: NAME -->``, comments and blank lines dropped."""
    match = re.search(rf"<!-- ci: {re.escape(name)} -->\s*```\w*\n(.*?)```", README.read_text(), re.S)
    if match is None:
        sys.exit(f"{README}: no block marked <!-- ci: {name} -->")
    lines = [re.sub(r"\s+#.*$", "", line).strip() for line in match.group(1).splitlines()]
    return [line for line in lines if line and not line.startswith("#")]


NUMBER = r"([-+]?\d+(?:\.\d+)?)"
NOTE = r"(?: \([^()]*\))?"
FIGURE = re.compile(r"([-+]?\d+(?:\.\d+)?)±(\d+(?:\.\d+)?)(%?)|≤(\d+(?:\.\d+)?)|\*")


def _literal(text: str) -> str:
    """``text`` as a pattern, a parenthesised note of the printed line allowed before each space, comma or
    semicolon (a note the data decide, such as a direction compared "(in the plane)", that the README need not
    quote)."""
    return re.sub(r"(\\ |,|;)", lambda m: NOTE + m.group(1), re.escape(text))


def line_check(quoted: str):
    """A quoted line -> (the regular expression a printed line must match, one check per figure: value -> bool)."""
    pattern, checks, end = "", [], 0
    for m in FIGURE.finditer(quoted):
        pattern += _literal(quoted[end : m.start()]) + NUMBER
        end = m.end()
        if m.group(1) is not None:
            centre, tolerance = float(m.group(1)), float(m.group(2))
            tolerance *= abs(centre) / 100 if m.group(3) else 1
            checks.append((m.group(0), lambda v, c=centre, t=tolerance: abs(v - c) <= t + 1e-12))
        elif m.group(4) is not None:
            checks.append((m.group(0), lambda v, b=float(m.group(4)): v <= b))
        else:
            checks.append(("*", lambda v: True))
    return re.compile(pattern + _literal(quoted[end:]) + NOTE), checks


def demo_problems(quoted: list[str], printed: list[str]) -> list[str]:
    """What of the ``quoted`` lines the ``printed`` ones do not hold (whitespace runs compared as one space): each
    quoted line is matched by the first printed line after the previous one's match that has its shape."""
    printed = [" ".join(line.split()) for line in printed]
    problems, start = [], 0
    for line in quoted:
        line = " ".join(line.split())
        pattern, checks = line_check(line)
        found = next(((i, m) for i in range(start, len(printed)) if (m := pattern.fullmatch(printed[i]))), None)
        if found is None:
            problems.append(f"not printed: {line}")
            continue
        start, m = found[0] + 1, found[1]
        for (spec, ok), value in zip(checks, m.groups()):
            if not ok(float(value)):
                problems.append(f"{value} where the README allows {spec}: {m.group(0)}")
    return problems


FIGURES = re.compile(r"<!-- figures from (\S+\.json)\n(.*?)-->", re.S)
FIGURE_LINE = re.compile(
    r"(?P<figure>[-+]?\d+(?:\.\d+)?)(?:\s*±(?P<tolerance>\d+(?:\.\d+)?)(?P<percent>%?))?\s*=\s*"
    r"(?:(?P<aggregate>min|max|median)\s+)?(?P<path>.+?)(?:\s+except\s+(?P<exclude>.+))?"
)


def _values(node, keys: list[str], exclude: set[str]) -> list:
    """The values at the key path ``keys`` under ``node`` (a ``*`` part: every key, or a list's every index, but
    ``exclude``)."""
    if not keys:
        return [node]
    key, rest = keys[0], keys[1:]
    if key == "*":
        items = enumerate(node) if isinstance(node, list) else node.items()
        return [v for k, child in items if str(k) not in exclude for v in _values(child, rest, exclude)]
    return _values(node[int(key)] if isinstance(node, list) else node[key], rest, exclude)


def documents() -> list[Path]:
    """The pages that may quote benchmarks' figures: the README and every Markdown page under docs/."""
    return [README, *sorted((ROOT / "docs").rglob("*.md"))]


def figure_problems(text: str, folder: Path) -> tuple[list[str], int]:
    """Check every figure declared in a ``<!-- figures from FILE.json`` comment of the Markdown ``text`` against the
    JSON files of ``folder`` -> (problems, how many figures were checked)."""
    problems, checked = [], 0
    for marker in FIGURES.finditer(text):
        above = text[: marker.start()].rstrip().split("\n\n")[-1]  # the paragraph or table the comment follows
        default = Path(marker.group(1)).name
        for line in filter(None, (line.strip() for line in marker.group(2).splitlines())):
            m = FIGURE_LINE.fullmatch(line)
            if m is None:
                problems.append(f"{default}: not a figure line: {line}")
                continue
            checked += 1
            figure = m.group("figure")
            if not re.search(rf"(?<![\d.]){re.escape(figure)}(?!\.?\d)", above):
                problems.append(f"{figure} is declared but not quoted in the text above it: {line}")
            keys = m.group("path").split("/")
            name = keys.pop(0) if keys[0].endswith(".json") else default
            exclude = {k.strip() for k in (m.group("exclude") or "").split(";") if k.strip()}
            try:
                values = _values(json.loads((folder / name).read_text()), keys, exclude)
            except (OSError, KeyError, IndexError, ValueError, AttributeError) as err:
                problems.append(f"{name}: no value at {m.group('path')} ({type(err).__name__}: {err}): {line}")
                continue
            aggregate = m.group("aggregate")
            if not values or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in values):
                problems.append(f"{name}: not numbers at {m.group('path')}: {values}")
                continue
            if aggregate is None and len(values) != 1:
                problems.append(f"{name}: {len(values)} values at {m.group('path')} without min, max or median")
                continue
            value = {"min": min, "max": max, "median": statistics.median, None: lambda v: v[0]}[aggregate](values)
            if m.group("tolerance") is None:
                decimals = len(figure.partition(".")[2])
                tolerance = 0.5 * 10**-decimals
            else:
                tolerance = float(m.group("tolerance")) * (abs(float(figure)) / 100 if m.group("percent") else 1)
            if not abs(value - float(figure)) <= tolerance * (1 + 1e-9):
                problems.append(f"{figure} where {name} holds {value:.6g} (allowed ±{tolerance:g}): {line}")
    return problems, checked


def main() -> None:
    what = sys.argv[1]
    if what == "install":
        lines = block("install")
        if lines[0] != TORCH_LINE:
            sys.exit(f"{README}: the install block's first line is {lines[0]!r}, CI expects {TORCH_LINE!r}")
        print("\n".join(lines[1:]))
    elif what == "test":
        print("\n".join(block("test")))
    elif what == "demo":
        quoted = block("demo output")
        problems = demo_problems(quoted, Path(sys.argv[2]).read_text().splitlines())
        if problems:
            sys.exit("README: the demo's figures are off what the README quotes:\n  " + "\n  ".join(problems))
        print(f"README: the demo's {len(quoted)} quoted lines hold, each figure within its tolerance")
    elif what == "figures":
        problems, checked = [], 0
        for page in documents():
            found, count = figure_problems(page.read_text(), ROOT / "bench" / "results")
            problems += [f"{page.relative_to(ROOT)}: {problem}" for problem in found]
            checked += count
        if problems:
            sys.exit("figures off what the benchmarks wrote:\n  " + "\n  ".join(problems))
        print(f"{checked} figures from bench/results hold, each within its tolerance")
    else:
        sys.exit(__doc__)


if __name__ == "__main__":
    main()
