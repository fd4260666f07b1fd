"""The README's commands and figures that CI runs and checks.

    python .ci/readme.py install   the install commands, one a line, as CI runs them
    python .ci/readme.py test      the test command
    python .ci/readme.py demo OUT  check that every line the README quotes from the demo is in OUT (its stdout)

The README marks each block with a comment line before it: ``<!-- ci: install -->``, ``<!-- ci: test -->``,
``<!-- ci: demo output -->``. CI installs torch itself (the pinned version: here the CPU build; PyTorch's CPU
wheel index in the README's first line cannot be reached from CI's machine), so the README's torch line must be
exactly TORCH_LINE and is left out of what ``install`` prints.
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
        printed = {" ".join(line.split()) for line in Path(sys.argv[2]).read_text().splitlines()}
        stale = [line for line in block("demo output") if " ".join(line.split()) not in printed]
        if stale:
            sys.exit("README: the demo does not print these quoted lines any more:\n  " + "\n  ".join(stale))
        print(f"README: the demo's {len(block('demo output'))} quoted lines are what it prints")
    else:
        sys.exit(__doc__)


if __name__ == "__main__":
    main()
