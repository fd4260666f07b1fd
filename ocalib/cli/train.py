"""``ocalib train``: the Lightning training application (``train/``); all arguments go to its LightningCLI.

``ocalib train`` alone or with ``--help`` prints the application's overview from here, without importing
Lightning (several seconds, more on a first run); a sub-command's ``--help`` (``ocalib train fit --help``) is the
LightningCLI's own, which lists every option of the trainer, the model and the data.
"""

from __future__ import annotations

import argparse
import re

from ocalib.errors import InputError

# The data modules' options that take a list of folders (jsonargparse's own message for a bare folder is a paragraph)
LIST_OPTIONS = re.compile(r"--data\.(init_args\.)?(val_)?sequences")
# The LightningCLI's sub-commands (LightningCLI.subcommands(); a test keeps the two the same).
SUBCOMMANDS = {
    "fit": "train, validating as it goes; resume with --ckpt_path runs/NAME/version_N/checkpoints/last.ckpt",
    "validate": "one evaluation epoch over the validation set",
    "test": "one evaluation epoch over the test set",
    "predict": "run the model over the predict set",
}
HELP = """usage: ocalib train [-c CONFIG] {{fit,validate,test,predict}} ...

Train the depth and pose networks: the LightningCLI of ocalib.train (also python -m ocalib.train).

subcommands:
{subcommands}

e.g. ocalib train fit --config configs/train/quick.yaml (a run of minutes) or configs/train/synthetic-cpu.yaml
(the shipped checkpoint's recipe). Every option of a subcommand (trainer, model, data, --print_config):
ocalib train fit --help (it imports Lightning first: several seconds)."""


def help_text() -> str:
    """The overview ``ocalib train --help`` prints."""
    return HELP.format(subcommands="\n".join(f"  {name:<10} {text}" for name, text in SUBCOMMANDS.items()))


def add_parser(subparsers, name: str) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        name,
        add_help=False,
        prefix_chars="+",  # every option, --help included, belongs to the LightningCLI
        help="train the depth and pose networks: fit | validate | test --config configs/train/NAME.yaml",
        description="LightningCLI of train/: ocalib train fit --config configs/train/synthetic-cpu.yaml",
    )
    p.add_argument("args", nargs=argparse.REMAINDER, help="LightningCLI arguments (ocalib train --help)")
    return p


def run(args) -> int:
    if args.args in ([], ["-h"], ["--help"]):  # without a sub-command: the overview (1, as ocalib alone)
        print(help_text())
        return 0 if args.args else 1
    check_lists(args.args)
    import sys

    from ocalib.train.cli import main

    argv, sys.argv = sys.argv, ["ocalib train", *args.args]  # the LightningCLI reads sys.argv (warns when given both)
    try:
        main()
    finally:
        sys.argv = argv
    return 0


def check_lists(argv: list[str]) -> None:
    """An :class:`InputError` (one line) where a list option of :data:`LIST_OPTIONS` is given one folder without the
    brackets of a list (``--data.sequences=DIR``, ``--data.sequences DIR``), before Lightning is imported."""
    for option, following in zip(argv, [*argv[1:], None]):
        name, equals, value = option.partition("=")
        if not LIST_OPTIONS.fullmatch(name):
            continue
        value = value if equals else following
        if value is not None and not value.strip().startswith("[") and value.strip() not in ("null", "None"):
            raise InputError(f"{name} takes a list: {name} '[{value}]' (several: '[DIR1, DIR2]')")
