"""``ocalib train``: the Lightning training application (``train/``); all arguments go to its LightningCLI."""

from __future__ import annotations

import argparse


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
    import sys

    from ocalib.train.cli import main

    argv, sys.argv = sys.argv, ["ocalib train", *args.args]  # the LightningCLI reads sys.argv (warns when given both)
    try:
        main()
    finally:
        sys.argv = argv
    return 0
