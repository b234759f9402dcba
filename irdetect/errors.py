"""The one exception type the CLI turns into exit code 2 and a single line."""

from __future__ import annotations

import os
from contextlib import contextmanager


class InputError(ValueError):
    """Bad user input: a file that cannot be read, a bad option value, a bad config.

    Parameters
    ----------
    message : str
        What is wrong, in one line.
    path : str or os.PathLike, optional
        The file concerned; it is named in the message.
    """

    def __init__(self, message: str, path: str | os.PathLike | None = None):
        self.path = None if path is None else os.fspath(path)
        text = message if self.path is None else f"{self.path}: {message}"
        super().__init__(text)


@contextmanager
def refused_settings(path: str | os.PathLike | None = None):
    """Turn the ValueError a stage raises on a parameter into an InputError naming the
    configuration file ``path``: wrap a dry run of the stages on blank input with it, so
    a bad value fails before a run instead of a traceback in the middle of one."""
    try:
        yield
    except ValueError as exc:
        raise InputError(f"bad configuration value: {exc}", path) from None
