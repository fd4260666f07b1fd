"""Write docs/reference/cli.md, the command line's reference, from the argparse parsers of ``ocalib.cli``.

    python docs/cli_reference.py          rewrite docs/reference/cli.md
    python docs/cli_reference.py --check  exit 1 where the file differs from what the parsers give

tests/test_docs.py runs the check, so an option added to a command without refreshing the page fails. A default
that depends on the machine (``synth --workers``: the CPUs, at most 4) is shown as on a machine of 4 CPUs, so that
the page is the same wherever it is made.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from unittest import mock

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "reference" / "cli.md"


def _cell(text: str) -> str:
    return " ".join(str(text).split()).replace("|", "\\|")


def _help(action: argparse.Action) -> str:
    text = action.help or ""
    if "%(" in text:
        text = text % {**vars(action), "prog": ""}
    return text


def _argument(action: argparse.Action) -> str:
    if action.nargs == 0:
        return ""
    if action.choices is not None and not isinstance(action.choices, dict):
        return "{" + ",".join(map(str, action.choices)) + "}"
    metavar = action.metavar or (action.dest.upper() if action.option_strings else action.dest)
    metavar = " ".join(metavar) if isinstance(metavar, tuple) else metavar
    return {"?": f"[{metavar}]", "*": f"[{metavar} ...]", "+": f"{metavar} [...]"}.get(action.nargs, metavar)


def _default(action: argparse.Action) -> str:
    default = action.default
    if action.nargs == 0 or default is None or default is argparse.SUPPRESS or action.required:
        return ""
    return f"`{' '.join(map(str, default)) if isinstance(default, list | tuple) else default}`"


def command_markdown(name: str, parser: argparse.ArgumentParser) -> str:
    """One command's section: its description and a table of its arguments."""
    lines = [f"## `ocalib {name}`", "", _cell(parser.description or ""), ""]
    if name == "train":  # every option is the LightningCLI's (prefix "+": argparse sees none of them)
        from ocalib.cli.train import help_text

        return "\n".join([*lines, "```text", help_text(), "```", ""])
    rows = []
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction) or action.help == argparse.SUPPRESS:
            continue
        names = ", ".join(f"`{s}`" for s in action.option_strings) or f"`{action.dest}`"
        argument = _argument(action)
        rows.append(
            f"| {names} | {_cell(argument) and f'`{_cell(argument)}`'} | {_default(action)} | {_cell(_help(action))} |"
        )
    lines += ["| argument | value | default | what it does |", "|---|---|---|---|", *rows, ""]
    return "\n".join(lines)


def cli_markdown() -> str:
    """The whole page."""
    from ocalib.cli import build_parser

    with mock.patch.object(os, "cpu_count", return_value=4):
        parser = build_parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    summaries = {a.dest: a.help for a in commands._choices_actions}
    page = [
        "# Command-line reference",
        "",
        "Every command of `ocalib` and its arguments, generated from the command line's own parsers by",
        "`python docs/cli_reference.py` (`ocalib COMMAND --help` prints the same). The guide says when to use which:",
        "[guide.md](../guide.md).",
        "",
        "| command | what it does |",
        "|---|---|",
        *(f"| [`ocalib {name}`](#ocalib-{name}) | {_cell(summaries[name])} |" for name in commands.choices),
        "",
    ]
    page += [command_markdown(name, sub) for name, sub in commands.choices.items()]
    return "\n".join(page).rstrip("\n") + "\n"


def main() -> int:
    text = cli_markdown()
    if sys.argv[1:] == ["--check"]:
        if not PAGE.exists() or PAGE.read_text() != text:
            print(
                f"{PAGE.relative_to(ROOT)} is not what the parsers give: python docs/cli_reference.py", file=sys.stderr
            )
            return 1
        return 0
    PAGE.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
