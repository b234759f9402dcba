"""The one exception type the CLI turns into exit code 2 and a single line."""

from __future__ import annotations

import os
import resource
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
    keys : tuple of str, optional
        The configuration or scenario keys whose values are at fault, so a command can
        name the options that set them (:func:`name_options`).
    """

    def __init__(self, message: str, path: str | os.PathLike | None = None, *,
                 keys: tuple[str, ...] = ()):
        self.path = None if path is None else os.fspath(path)
        self.message = message
        self.keys = tuple(keys)
        text = message if self.path is None else f"{self.path}: {message}"
        super().__init__(text)


def name_options(exc: InputError, options: dict[str, str]) -> InputError:
    """``exc`` with the options that set its keys in front of its message.

    Parameters
    ----------
    exc : InputError
        An error whose ``keys`` name the values at fault.
    options : dict
        Key -> the option as the user gave it (``{"height": "--size 0x0"}``), for the keys
        an option set.

    Returns
    -------
    InputError
        ``"--size 0x0: height must be >= 1, got 0"``; ``exc`` itself when no option set
        any of its keys (the value came from a preset file, which it names).
    """
    named = list(dict.fromkeys(options[k] for k in exc.keys if k in options))
    if not named:
        return exc
    return InputError(f"{', '.join(named)}: {exc.message}", exc.path, keys=exc.keys)


@contextmanager
def refused_settings(path: str | os.PathLike | None = None):
    """Turn the ValueError a stage raises on a parameter into an InputError naming the
    configuration file ``path``: wrap a dry run of the stages on blank input with it, so
    a bad value fails before a run instead of a traceback in the middle of one."""
    import cv2

    try:
        with _memory_cap(DRY_RUN_BYTES):
            yield
    except ValueError as exc:
        raise InputError(f"bad configuration value: {exc}", path) from None
    except (MemoryError, cv2.error):
        raise InputError("a configuration value asks for more memory than a run on blank "
                         f"32 x 32 frames may take ({DRY_RUN_BYTES >> 30} GiB)", path) from None


#: address space the dry run of the settings may add (it runs on 32 x 32 frames: a value
#: that wants more would take far more on real frames; with overcommit such allocations
#: succeed and the kernel kills the process later instead of raising MemoryError)
DRY_RUN_BYTES = 2 << 30


@contextmanager
def _memory_cap(extra: int):
    """Lower the soft RLIMIT_AS to the current address space + ``extra`` for the block.

    Only while this is the process's only Python thread: the limit is the process's, and
    another thread's allocation must not fail for it (a Dask worker running tasks side by
    side, a caller's thread pool); there the dry run runs uncapped."""
    import threading

    others = [t for t in threading.enumerate() if t is not threading.current_thread()
              and t.name != "irdetect-parent-watch"]       # a batch worker's idle watch
    if others:
        yield
        return
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    try:
        with open("/proc/self/statm") as fh:
            used = int(fh.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    except OSError:             # not Linux: no cap
        used = None
    cap = None if used is None else used + extra
    if cap is None or (soft != resource.RLIM_INFINITY and soft <= cap) or \
            (hard != resource.RLIM_INFINITY and hard < cap):
        yield
        return
    resource.setrlimit(resource.RLIMIT_AS, (cap, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


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
