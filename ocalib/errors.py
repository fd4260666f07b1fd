"""Errors about the user's input (the command line prints them as one line and exits with code 2), and Ctrl-C."""

import contextlib
import signal


class InputError(ValueError):
    """Bad input (a file, a frame, a shape): the message names the file, line or frame."""


def read_text(path, what: str = "text file") -> str:
    """The text of the file ``path``; a missing path, a folder or a binary file is an :class:`InputError` naming it.

    ``what`` names what the file should have been (``"pose file"``), for the message.
    """
    from pathlib import Path

    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path}: a folder, not a {what}")
    if not path.is_file():
        raise InputError(f"{path}: no such {what}")
    data = path.read_bytes()
    try:
        if b"\0" in data:
            raise UnicodeDecodeError("utf-8", data, data.index(b"\0"), data.index(b"\0") + 1, "NUL byte")
        return data.decode("utf-8")
    except UnicodeDecodeError as err:
        raise InputError(f"{path}: not a {what} (binary data at byte {err.start})") from None


@contextlib.contextmanager
def deferred_interrupts():
    """Ctrl-C (SIGINT) inside the block takes effect when it ends: the handler in force then runs once. For work that
    an interrupt would leave broken (numba's compiler), and for starting worker processes by fork: they inherit the
    deferring handler and so leave Ctrl-C to the main process. Outside the main thread, a no-op."""
    pressed: list[int] = []
    try:
        previous = signal.signal(signal.SIGINT, lambda signum, frame: pressed.append(signum))
    except ValueError:  # not the main thread, where signals cannot be set
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if pressed:
        if callable(previous):
            previous(signal.SIGINT, None)
        elif previous != signal.SIG_IGN:
            raise KeyboardInterrupt
