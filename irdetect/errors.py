"""The one exception type the CLI turns into exit code 2 and a single line."""

from __future__ import annotations

import os
import stat
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


def check_input_file(path: str | os.PathLike, what: str = "file") -> None:
    """Refuse a missing path or one that is not a regular file (a folder, a FIFO, a device,
    a socket) before anything opens it: opening a FIFO blocks until a writer appears.

    Raises
    ------
    InputError
        ``"{what} not found"``, or not a regular file.
    """
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise InputError(f"{what} not found", path) from None
    except OSError as exc:
        raise InputError(f"cannot read the {what} ({exc.strerror})", path) from None
    if stat.S_ISDIR(mode):
        raise InputError(f"a folder, not a {what}", path)
    if not stat.S_ISREG(mode):
        raise InputError(f"not a regular file (a FIFO, device or socket); expected a {what}",
                         path)
