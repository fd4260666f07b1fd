"""The ``ocalib`` command line: one module per sub-command.

Each module in :data:`COMMANDS` defines ``add_parser(subparsers, name)`` (returning its parser) and
``run(args) -> int``. Command modules import torch and friends inside ``run`` so that
``ocalib --help`` stays fast.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from ocalib.errors import InputError

# command name -> module under ocalib.cli, one line each.
COMMANDS = {
    "simulate": "simulate",
    "synth": "synth",
    "calibrate-poses": "calibrate_poses",
    "calibrate": "calibrate",
    "demo": "demo",
    "predict": "predict",
    "evaluate": "evaluate",
    "train": "train",
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="ocalib", description="On-line calibration of non-overlapping multi-camera rigs from ego-motion."
    )
    parser.add_argument("--version", action="version", version=f"ocalib {__import__('ocalib').__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, module in COMMANDS.items():
        mod = importlib.import_module(f"ocalib.cli.{module}")
        p = mod.add_parser(sub, name)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help()
        return 1
    try:
        return int(args._run(args) or 0)
    except (InputError, FileNotFoundError) as err:
        print(f"ocalib {args.command}: error: {error_message(err)}", file=sys.stderr)
        return 2


def error_message(err: Exception) -> str:
    """The message of ``err``; for an error re-raised from a DataLoader worker (whose message is the worker's
    whole traceback), the original message only."""
    text = str(err)
    if "Original Traceback" in text:
        prefix = f"{type(err).__module__}.{type(err).__name__}: "
        lines = [line[len(prefix):] for line in text.splitlines() if line.startswith(prefix)]
        if lines:
            return lines[-1]
    return text
