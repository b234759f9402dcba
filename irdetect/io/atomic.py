"""Outputs that appear whole or not at all, never over an input or another run's output.

Every irdetect writer goes through :func:`atomic_output`:

- the output is checked before any work (folder exists and is writable, a regular file
  or nothing at the path, not one of the run's inputs by resolved path or inode, no
  existing file without ``force``);
- an exclusive lock, ``.NAME.irdetect-lock`` beside the output, is held for the run, so a
  second run writing the same output fails at once (exit 2) instead of replacing the
  first one's file; the lock is an ``flock``, released by the kernel when a run dies;
- the data go to a hidden temporary ``.NAME.irdetect-XXXX.tmp`` that is renamed into
  place only when everything succeeded, and removed on any error, on SIGINT and on
  SIGTERM (``irdetect.cli`` turns both into ``KeyboardInterrupt``); temporaries of a run
  killed with SIGKILL are removed by the next run that takes the lock;
- without ``force`` the rename does not replace a file that appeared during the run
  (``os.link`` then unlink, which fails on an existing name).

HDF5 writers write through :class:`GuardedFile`: a failed write (disk full, file size
limit, I/O error) is recorded instead of reaching the HDF5 library, whose state after a
failed write is unreliable (it crashed at exit), and reported as one ``InputError``.
"""

from __future__ import annotations

import errno
import fcntl
import io
import os
import shutil
import stat
import sys
import tempfile
from contextlib import contextmanager
from pathlib import Path

from irdetect.errors import InputError

LOCK_SUFFIX = ".irdetect-lock"
TEMP_TAG = ".irdetect-"

#: the SIGINT / SIGTERM that arrived (``on_signal``), first first; no output is committed
#: after one, even when the signal's exception was swallowed by a library callback
received: list[int] = []
#: HDF5 writers open: the signal's exception must not be raised inside the library's
#: callbacks into GuardedFile, so they raise it themselves at their next block
_deferring = 0


def on_signal(signum, frame) -> None:
    """The SIGINT / SIGTERM handler ``irdetect.cli`` installs: note the signal and raise
    ``KeyboardInterrupt``, or, while an HDF5 writer is open, leave that to its next
    ``check`` (after each block it writes: within milliseconds)."""
    received.append(signum)
    if not _deferring:
        raise KeyboardInterrupt


@contextmanager
def deferred_signals():
    """While in the block, ``on_signal`` only notes a signal (see ``_deferring``)."""
    global _deferring
    _deferring += 1
    try:
        yield
    finally:
        _deferring -= 1


def same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """Whether two paths name one file (resolved path, or device and inode: symlinks and
    hard links included); False when either does not exist."""
    try:
        return os.path.realpath(a) == os.path.realpath(b) or os.path.samefile(a, b)
    except OSError:
        return False


def check_output_place(path: Path, inputs=()) -> None:
    """The output's folder exists and is writable, and ``path`` is none of ``inputs``.

    Raises
    ------
    InputError
        Naming ``path``.
    """
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise InputError(f"output folder {str(folder)!r} does not exist", path)
    if not os.access(folder, os.W_OK):
        raise InputError(f"output folder {str(folder)!r} is not writable", path)
    for source in inputs:
        if source is not None and same_file(source, path):
            raise InputError(f"the output is the input {os.fspath(source)!r}; give another "
                             "output name", path)


def leave(output, exc_info, close) -> bool:
    """Leave a writer: ``close(ok)`` (ok: the block succeeded), then the ``atomic_output``
    context ``output``, which commits or removes the temporary; an error of ``close``
    becomes the block's error. Returns what ``__exit__`` returns."""
    exc_type, exc, tb = exc_info
    try:
        close(exc_type is None)
    except BaseException:
        if exc_type is None:
            exc_type, exc, tb = sys.exc_info()
        output.__exit__(exc_type, exc, tb)
        raise
    return output.__exit__(exc_type, exc, tb)


def check_output_path(path: str | os.PathLike, force: bool = False,
                      inputs=()) -> Path:
    """Check that ``path`` can be written before any work is done.

    Parameters
    ----------
    path : str or os.PathLike
        The output file.
    force : bool
        Allow replacing an existing file.
    inputs : iterable of path
        The run's inputs; the output may be none of them, even with ``force``.

    Raises
    ------
    InputError
        The folder is missing or not writable, the path is an input, a folder or not a
        regular file, or it exists and ``force`` is False.
    """
    path = Path(path)
    check_output_place(path, inputs)
    if path.is_dir():
        raise InputError("output path is a folder", path)
    if path.exists() and not stat.S_ISREG(os.stat(path).st_mode):
        raise InputError("output path exists and is not a regular file", path)
    if path.exists() and not force:
        _clear_dead_run(path)
        raise InputError("output exists; use --force to overwrite it", path)
    return path


def _clear_dead_run(path: Path) -> None:
    """Remove a dead run's lock and temporaries beside ``path`` when no run holds the
    lock: a run killed with SIGKILL after it committed its output, before it removed
    them, left them (``kill -9`` at random moments, tests/test_kill9.py), and the next run
    refuses the output before it would take the lock."""
    try:
        with OutputLock(path):
            pass
    except InputError:              # a live run holds it, or the folder is not writable
        pass


class OutputLock:
    """An exclusive ``flock`` on ``.NAME.irdetect-lock`` beside an output.

    Raises ``InputError`` at once when another run holds it. While held, any
    ``.NAME.irdetect-*`` temporary beside the output is a dead run's and is removed.
    """

    def __init__(self, path: Path):
        self.path = Path(path)
        self.lock = self.path.parent / f".{self.path.name}{LOCK_SUFFIX}"
        self._fd: int | None = None

    def __enter__(self) -> "OutputLock":
        while True:
            try:
                fd = os.open(self.lock, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
            except OSError as exc:
                raise InputError(f"cannot write in the output folder ({exc.strerror})",
                                 self.path) from None
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                raise InputError("another irdetect run is writing this output", self.path) \
                    from None
            try:
                if os.stat(self.lock).st_ino == os.fstat(fd).st_ino:
                    break
            except FileNotFoundError:
                pass
            os.close(fd)       # its holder removed it between our open and lock: retry
        self._fd = fd
        self._remove_stale()
        return self

    def _remove_stale(self) -> None:
        prefix = f".{self.path.name}{TEMP_TAG}"
        for entry in os.scandir(self.path.parent):
            if entry.name.startswith(prefix) and entry.name != self.lock.name:
                if entry.is_dir(follow_symlinks=False):
                    shutil.rmtree(entry.path, ignore_errors=True)
                else:
                    _unlink(entry.path)

    def __exit__(self, *exc) -> None:
        _unlink(self.lock)     # before closing, so no waiter locks a removed file
        os.close(self._fd)


@contextmanager
def atomic_output(path: str | os.PathLike, *, force: bool = False, inputs=(),
                  suffix: str = "", folder: bool = False):
    """Yield a temporary path beside ``path`` that becomes ``path`` when the block succeeds.

    Parameters
    ----------
    path : str or os.PathLike
        The output (checked with :func:`check_output_path` unless ``folder``).
    force : bool
        Replace an existing output.
    inputs : iterable of path
        The run's inputs, never written over.
    suffix : str
        Ending of the temporary's name (writers that pick a format by suffix need it).
    folder : bool
        The output is a folder (PNG frames); the caller has checked the path.

    Yields
    ------
    str
        The temporary path (an empty file, or an empty folder with ``folder``).

    Raises
    ------
    InputError
        Bad output path, another run holds the lock, a file appeared at the path during
        the run without ``force``, or a write error (disk full, ...).
    """
    path = Path(path) if folder else check_output_path(path, force, inputs)
    with OutputLock(path):
        prefix = f".{path.name}{TEMP_TAG}"
        try:
            if folder:
                tmp = tempfile.mkdtemp(prefix=prefix, suffix=".tmp", dir=path.parent)
            else:
                fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=".tmp" + suffix,
                                           dir=path.parent)
                os.close(fd)
        except OSError as exc:
            raise InputError(f"cannot write beside the output ({exc.strerror})", path) \
                from None
        try:
            yield tmp
            if received:
                raise KeyboardInterrupt
            for source in inputs:
                if source is not None and same_file(source, path):
                    raise InputError("the output became the input during the run", path)
            try:
                os.chmod(tmp, (0o777 if folder else 0o666) & ~_umask())  # mkstemp: 0600
                _commit(tmp, path, force, folder)
            except OSError as exc:
                raise write_error(exc, path) from None
        finally:
            if os.path.isdir(tmp) and not os.path.islink(tmp):
                shutil.rmtree(tmp, ignore_errors=True)
            else:
                _unlink(tmp)


def _commit(tmp: str, path: Path, force: bool, folder: bool) -> None:
    if folder:
        if path.is_dir():
            # the caller made sure it holds PNG frames only; move it aside first so
            # the new folder appears in one rename
            old = tempfile.mkdtemp(prefix=f".{path.name}{TEMP_TAG}", suffix=".old",
                                   dir=path.parent)
            os.rmdir(old)
            os.rename(path, old)
            os.rename(tmp, path)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.rename(tmp, path)
    elif force:
        os.replace(tmp, path)
    else:
        try:
            os.link(tmp, path)          # fails on an existing name, unlike rename
        except FileExistsError:
            raise InputError("output appeared during the run; use --force to overwrite it",
                             path) from None
        except OSError as exc:
            if exc.errno not in (errno.EPERM, errno.ENOTSUP, errno.EXDEV, errno.EMLINK):
                raise
            if path.exists():           # no hard links here (FAT, some FUSE mounts)
                raise InputError("output appeared during the run; use --force to "
                                 "overwrite it", path) from None
            os.replace(tmp, path)


def write_error(exc: OSError, path) -> InputError:
    """The one-line error of a failed write (disk full, no permission, read-only, ...)."""
    reason = exc.strerror or str(exc)
    if exc.errno == errno.EFBIG:
        reason = "file too large (file size limit reached)"
    return InputError(f"cannot write the output: {reason}", path)


class GuardedFile(io.RawIOBase):
    """A file for ``h5py.File(GuardedFile(tmp), "w")`` that never shows HDF5 a write error.

    The first failed write or truncate is stored in ``error`` and every later write is
    dropped; the writer checks :meth:`check` after each block and at the end, and the
    file, whose content is then garbage, is removed by :func:`atomic_output`.
    """

    def __init__(self, path: str, output):
        super().__init__()
        self._raw = open(path, "w+b", buffering=0)
        self.output = output
        self.error: OSError | None = None

    def readable(self) -> bool:
        return True

    def writable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def seek(self, pos: int, whence: int = 0) -> int:
        return self._raw.seek(pos, whence)

    def tell(self) -> int:
        return self._raw.tell()

    def readinto(self, buffer) -> int:
        return self._raw.readinto(buffer)

    def write(self, data) -> int:
        view = memoryview(data).cast("B")
        if self.error is None:
            try:
                done = 0
                while done < len(view):
                    done += self._raw.write(view[done:])
            except OSError as exc:
                self.error = exc
        return len(view)

    def truncate(self, size: int | None = None) -> int:
        if self.error is None:
            try:
                return self._raw.truncate(size)
            except OSError as exc:
                self.error = exc
        return self.tell() if size is None else size

    def check(self) -> None:
        """Raise the stored write error as an ``InputError`` naming the output."""
        if self.error is not None:
            raise write_error(self.error, self.output)

    def close(self) -> None:
        if not self.closed:
            try:
                self._raw.close()
            except OSError as exc:
                self.error = self.error or exc
        super().close()


def _unlink(path) -> None:
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
