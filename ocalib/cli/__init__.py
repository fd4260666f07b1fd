"""The ``ocalib`` command line: one module per sub-command.

Each module in :data:`COMMANDS` defines ``add_parser(subparsers, name)`` (returning its parser) and
``run(args) -> int``. Command modules import torch and friends inside ``run`` so that
``ocalib --help`` stays fast.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import signal
import sys
import time
from pathlib import Path

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
    "export": "export",
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


# options naming what a command writes: listed after a Ctrl-C when they were written to
OUTPUT_OPTIONS = ("out", "trace", "plot", "plots", "tensorboard", "trajectories")
# options naming a file a command writes when it has finished: checked before it starts, so that a mistake there
# costs no work
FILE_OUTPUTS = {
    "calibrate": ("out", "trace", "plot"),
    "calibrate-poses": ("out", "trace", "plot"),
    "evaluate": ("out",),
    "export": ("out",),
}


def main(argv: list[str] | None = None) -> int:
    # numpy's BLAS threads spin between calls on the cores the stream's own threads need, and the commands' matrices
    # are small: one thread (where numpy is not imported yet, as in a command's own process; a user's setting stays)
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help()
        return 1
    start = time.time()
    with _noting_interrupts() as interrupted:
        try:
            if getattr(args, "device", None) is not None:
                check_device(args.device)
            check_outputs(args)
            return int(args._run(args) or 0)
        except (InputError, OSError) as err:
            if interrupted:
                return _interrupted(args, start, KeyboardInterrupt())
            print(f"ocalib {args.command}: error: {error_message(err)}", file=sys.stderr)
            return 2
        except KeyboardInterrupt as err:  # Ctrl-C; a command may say what it had written in the exception's message
            return _interrupted(args, start, err)
        except Exception:
            if interrupted:  # an error that Ctrl-C caused, e.g. in a compiler it interrupted (numba's)
                return _interrupted(args, start, KeyboardInterrupt())
            raise


def _interrupted(args: argparse.Namespace, start: float, err: KeyboardInterrupt) -> int:
    """Say that ``args.command`` was interrupted and what it had written (or the message of ``err``) -> 130."""
    written = written_since(args, start)
    what = str(err) or (f"written so far (incomplete): {', '.join(written)}" if written else "nothing written")
    sys.excepthook = _quiet
    print(f"\nocalib {args.command}: interrupted; {what}", file=sys.stderr)
    return 130


def _quiet(*exc_info) -> None:
    """``sys.excepthook`` once Ctrl-C is pressed: the loader's helper thread (multiprocessing's resource sharer,
    which reports through it) breaks as the interruption winds the workers down, and its error, printed from then on
    to the process's end, is the interruption's echo, not news."""


@contextlib.contextmanager
def _noting_interrupts():
    """Ctrl-C raises KeyboardInterrupt as usual, and is noted in the list yielded (non-empty once pressed), so that
    an error it causes where the KeyboardInterrupt is caught or lost is still reported as the interruption."""
    noted: list[int] = []

    def handler(signum, frame):
        noted.append(signum)
        sys.excepthook = _quiet  # from the moment the workers start winding down, not only once the line is out
        raise KeyboardInterrupt

    try:
        previous = signal.signal(signal.SIGINT, handler)
    except ValueError:  # not the main thread: signals cannot be set, Python's default stays
        yield noted
        return
    try:
        yield noted
    finally:
        signal.signal(signal.SIGINT, previous)


def check_device(device: str) -> None:
    """An :class:`InputError` unless ``device`` names a torch device that this machine has."""
    if device == "cpu":  # every machine's, the default: no torch to import for it before the input is checked
        return
    import torch

    try:
        dev = torch.device(device)
    except (RuntimeError, ValueError):
        raise InputError(f"--device {device}: not a torch device (cpu, cuda, cuda:N)") from None
    if dev.type == "cpu":
        return
    module = getattr(torch, dev.type, None)
    available = getattr(module, "is_available", None)
    if dev.type == "mps":
        available = torch.backends.mps.is_available
    if available is None or not available():
        hint = " (this torch is a CPU build)" if dev.type == "cuda" and torch.version.cuda is None else ""
        raise InputError(f"--device {device}: no {dev.type.upper()} device on this machine{hint}; use --device cpu")
    count = getattr(module, "device_count", None)
    if dev.index is not None and count is not None and dev.index >= count():
        raise InputError(f"--device {device}: this machine has {count()} {dev.type.upper()} device(s)")


def check_outputs(args: argparse.Namespace) -> None:
    """An :class:`InputError` where an output file of :data:`FILE_OUTPUTS` names a folder, or a folder that is not
    there (``evaluate --out`` excepted: it makes its folders)."""
    for option in FILE_OUTPUTS.get(args.command, ()):
        value = getattr(args, option, None)
        if not value:
            continue
        path = Path(value)
        if path.is_dir():
            raise InputError(f"{path}: a folder; --{option} names the file to write")
        if args.command != "evaluate" and not path.resolve().parent.is_dir():
            raise InputError(f"{path}: no folder {path.parent} to write it in (--{option})")


def written_since(args: argparse.Namespace, start: float) -> list[str]:
    """The output paths of ``args`` (:data:`OUTPUT_OPTIONS`) holding a file modified since ``start``."""
    written = []
    for option in OUTPUT_OPTIONS:
        value = getattr(args, option, None)
        if not value:
            continue
        path = Path(value)
        files = [path] if path.is_file() else (p for p in path.rglob("*") if p.is_file()) if path.is_dir() else []
        if any(f.stat().st_mtime >= start - 1 for f in files):
            written.append(str(path))
    return written


def error_message(err: Exception) -> str:
    """The message of ``err``; for an error re-raised from a DataLoader worker (whose message is the worker's
    whole traceback), the original message only; for an OS error, the file and what is wrong with it."""
    if isinstance(err, OSError) and err.filename is not None and err.strerror:
        return f"{err.filename}: {err.strerror[0].lower()}{err.strerror[1:]}"
    text = str(err)
    if "Original Traceback" in text:
        prefix = f"{type(err).__module__}.{type(err).__name__}: "
        lines = [line[len(prefix) :] for line in text.splitlines() if line.startswith(prefix)]
        if lines:
            return lines[-1]
    return text
