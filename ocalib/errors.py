"""Errors about the user's input. The command line prints them as one line and exits with code 2."""


class InputError(ValueError):
    """Bad input (a file, a frame, a shape): the message names the file, line or frame."""
