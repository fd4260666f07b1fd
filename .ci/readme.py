"""The README's commands and figures that CI runs and checks.

    python .ci/readme.py install   the install commands, one a line, as CI runs them
    python .ci/readme.py test      the test command
    python .ci/readme.py demo OUT  check every line the README quotes from the demo against OUT (its stdout)

The README marks each block with a comment line before it: ``<!-- ci: install -->``, ``<!-- ci: test -->``,
``<!-- ci: demo output -->``. CI installs torch itself (the pinned version: here the CPU build; PyTorch's CPU
wheel index in the README's first line cannot be reached from CI's machine), so the README's torch line must be
exactly TORCH_LINE and is left out of what ``install`` prints.

A quoted demo line is matched against the printed lines figure by figure: ``0.077±0.05`` is a figure within 0.05 of
0.077, ``0.112±5%`` one within 5 % of 0.112, ``≤20`` one at most 20, ``*`` any figure (not checked: it is
ill-conditioned); every other character must be as printed. A figure is digits, so a printed ``nan`` never matches.
"""

import re
import sys
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"
TORCH_LINE = "pip install torch==2.13.0 --index-url https://download.pytorch.org/whl/cpu"


def block(name: str) -> list[str]:
    """The lines of the fenced block after ``<!-- ci: NAME -->``, comments and blank lines dropped."""
    match = re.search(rf"<!-- ci: {re.escape(name)} -->\s*```\w*\n(.*?)```", README.read_text(), re.S)
    if match is None:
        sys.exit(f"{README}: no block marked <!-- ci: {name} -->")
    lines = [re.sub(r"\s+#.*$", "", line).strip() for line in match.group(1).splitlines()]
    return [line for line in lines if line and not line.startswith("#")]


NUMBER = r"([-+]?\d+(?:\.\d+)?)"
FIGURE = re.compile(r"([-+]?\d+(?:\.\d+)?)±(\d+(?:\.\d+)?)(%?)|≤(\d+(?:\.\d+)?)|\*")


def line_check(quoted: str):
    """A quoted line -> (the regular expression a printed line must match, one check per figure: value -> bool)."""
    pattern, checks, end = "", [], 0
    for m in FIGURE.finditer(quoted):
        pattern += re.escape(quoted[end : m.start()]) + NUMBER
        end = m.end()
        if m.group(1) is not None:
            centre, tolerance = float(m.group(1)), float(m.group(2))
            tolerance *= abs(centre) / 100 if m.group(3) else 1
            checks.append((m.group(0), lambda v, c=centre, t=tolerance: abs(v - c) <= t + 1e-12))
        elif m.group(4) is not None:
            checks.append((m.group(0), lambda v, b=float(m.group(4)): v <= b))
        else:
            checks.append(("*", lambda v: True))
    return re.compile(pattern + re.escape(quoted[end:])), checks


def demo_problems(quoted: list[str], printed: list[str]) -> list[str]:
    """What of the ``quoted`` lines the ``printed`` ones do not hold (whitespace runs compared as one space)."""
    printed = [" ".join(line.split()) for line in printed]
    problems = []
    for line in quoted:
        line = " ".join(line.split())
        pattern, checks = line_check(line)
        matches = [m for m in map(pattern.fullmatch, printed) if m]
        if not matches:
            problems.append(f"not printed: {line}")
            continue
        for m in matches[:1]:
            for (spec, ok), value in zip(checks, m.groups()):
                if not ok(float(value)):
                    problems.append(f"{value} where the README allows {spec}: {m.group(0)}")
    return problems


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
    else:
        sys.exit(__doc__)


if __name__ == "__main__":
    main()
