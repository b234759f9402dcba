"""HDF5 files written atomically: results, sequences, truth.

A writer fills a temporary file beside the output and renames it into place only when
everything succeeded, so a run that fails or is killed leaves no file at the output path;
an existing output is replaced only with ``force=True`` (``irdetect.io.atomic``). Tables are numpy structured
arrays stored as compound datasets (``irdetect.tables``); empty tables keep their fields.
"""

from __future__ import annotations

import json
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from irdetect import __version__, tables
from irdetect.errors import InputError, check_input_file
from irdetect.io.atomic import (GuardedFile, atomic_output, check_output_path,
                                deferred_signals, leave, received)
from irdetect.io.sources import OTHER_SEQUENCE_SUFFIXES


class AtomicH5:
    """An HDF5 file that appears at ``path`` only when the ``with`` block succeeds.

    Written through :func:`irdetect.io.atomic.atomic_output` (lock, hidden temporary,
    rename) and :class:`~irdetect.io.atomic.GuardedFile` (a disk-full or other write error
    becomes one ``InputError``, never a crash of the HDF5 library).

    Parameters
    ----------
    path : str or os.PathLike
        The output file.
    force : bool
        Replace an existing file.
    inputs : iterable of path
        The run's inputs: the output may be none of them.

    Examples
    --------
    >>> with AtomicH5("out.h5", force=True) as f:     # doctest: +SKIP
    ...     f.create_dataset("x", data=[1, 2, 3])
    """

    def __init__(self, path: str | os.PathLike, *, force: bool = False, inputs=()):
        self.path = check_output_path(path, force, inputs)
        self._output = atomic_output(self.path, force=force, inputs=inputs)
        self._deferred = deferred_signals()
        self._guard: GuardedFile | None = None
        self.file: h5py.File | None = None

    def __enter__(self) -> h5py.File:
        tmp = self._output.__enter__()
        self._deferred.__enter__()
        try:
            self._guard = GuardedFile(tmp, self.path)
            self.file = h5py.File(self._guard, "w")
        except BaseException:
            self._deferred.__exit__(None, None, None)
            self._output.__exit__(*sys.exc_info())
            raise
        return self.file

    def check(self) -> None:
        """Raise the first write error (disk full, ...) as an ``InputError`` now, or
        ``KeyboardInterrupt`` when SIGINT / SIGTERM arrived and a library swallowed it."""
        if received:
            raise KeyboardInterrupt
        self._guard.check()

    def __exit__(self, exc_type, exc, tb):
        return leave(self._output, (exc_type, exc, tb), self._close)

    def _close(self, ok: bool) -> None:
        try:
            self.file.close()
            self._guard.close()
        finally:
            self._deferred.__exit__(None, None, None)
        if ok:
            self.check()


class ResultsWriter(AtomicH5):
    """Write a results file (``docs/format.md``) atomically, streaming tables as they grow.

    Parameters
    ----------
    path : str or os.PathLike
        The output file.
    force : bool
        Replace an existing file.
    attrs : dict, optional
        Root attributes; ``irdetect_version`` is always added.
    inputs : iterable of path
        The run's inputs: the output may be none of them.

    Examples
    --------
    >>> with ResultsWriter("out.h5", attrs={"input": "seq.h5"}) as out:   # doctest: +SKIP
    ...     out.append("detections", detections_of_window)
    """

    #: appended rows are buffered and written in blocks of at least this many rows (one
    #: HDF5 resize + write per block, not per call: per-call writes cost ~1 ms each)
    FLUSH_ROWS = 4096

    def __init__(self, path, *, force: bool = False, attrs: dict | None = None, inputs=()):
        super().__init__(path, force=force, inputs=inputs)
        self.attrs = {"irdetect_version": __version__, **(attrs or {})}
        self._pending: dict[str, list] = {}
        self._n_pending: dict[str, int] = {}

    def __enter__(self):
        super().__enter__()
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            try:
                self.flush()
                for key, value in self.attrs.items():
                    self.file.attrs[key] = value
            except BaseException:
                super().__exit__(*sys.exc_info())    # closes and removes the temporary
                raise
        return super().__exit__(exc_type, exc, tb)

    def write(self, name: str, table: np.ndarray) -> None:
        """Store a whole table (structured array) as dataset ``/name``."""
        self.file.create_dataset(name, data=table, maxshape=(None,),
                                 chunks=(max(1, min(len(table), 4096)),) if len(table) else (256,))

    def append(self, name: str, rows: np.ndarray) -> None:
        """Append rows to table ``/name``, creating it (possibly empty) on first use.

        Rows are buffered (at most ``FLUSH_ROWS`` per table) and written on ``flush()``,
        which leaving the ``with`` block does.
        """
        self.check()
        if name not in self._pending:
            if name not in self.file:
                self.file.create_dataset(name, shape=(0,), dtype=rows.dtype, maxshape=(None,),
                                         chunks=(4096,))
            self._pending[name], self._n_pending[name] = [], 0
        if len(rows):
            self._pending[name].append(np.array(rows, copy=True))
            self._n_pending[name] += len(rows)
            if self._n_pending[name] >= self.FLUSH_ROWS:
                self._flush(name)

    def flush(self) -> None:
        """Write every buffered row to the file."""
        for name in self._pending:
            self._flush(name)

    def _flush(self, name: str) -> None:
        if not self._n_pending[name]:
            return
        rows = np.concatenate(self._pending[name])
        dset = self.file[name]
        n = dset.shape[0]
        dset.resize((n + len(rows),))
        dset[n:] = rows
        self._pending[name], self._n_pending[name] = [], 0
        self.check()


@dataclass
class Results:
    """A results file read back: its tables and root attributes.

    Attributes
    ----------
    path : str
    tables : dict
        Table name (``detections``, ``tracks``, ...) -> structured ndarray, or
        ``pandas.DataFrame`` (one column per field) when read with ``as_frame=True``.
    attrs : dict
        Root attributes (``irdetect_version``, ``input``, ``combined_length``, ...).
    """

    path: str
    tables: dict = field(default_factory=dict)
    attrs: dict = field(default_factory=dict)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.tables[name]

    def __contains__(self, name: str) -> bool:
        return name in self.tables

    @property
    def config(self) -> dict:
        """The resolved configuration the results were made with."""
        try:
            config = json.loads(self.attrs.get("config", "{}"))
        except (TypeError, ValueError):
            config = None
        if not isinstance(config, dict):
            raise InputError("attribute config is not a JSON object", self.path)
        return config

    def windows(self) -> tuple[int, int, bool]:
        """(length, step, tail) of the run's combined frames: the attributes
        ``combined_length`` / ``combined_step`` (what the run used, a short sequence's
        shorter windows too), else the configuration's ``combine`` table, else 12 frames
        every 12; ``tail`` the configuration's ``combine.tail`` (results written before the
        tail window have none: False)."""
        combine = self.config.get("combine", {})
        length = int(self.attrs.get("combined_length", combine.get("length", 12)))
        step = int(self.attrs.get("combined_step", combine.get("step", length)))
        return length, step, bool(combine.get("tail", False))


def read_results(path: str | os.PathLike, *, as_frame: bool | None = False) -> Results:
    """Read every table and root attribute of a results file.

    Parameters
    ----------
    path : str or os.PathLike
        A results file (``docs/format.md``).
    as_frame : bool or None
        False (default here): tables as numpy structured arrays; True: as
        ``pandas.DataFrame`` (pandas must be installed); None: DataFrames when pandas is
        installed, else arrays (the default of ``irdetect.read_results``).

    Raises
    ------
    InputError
        Missing or unreadable file.
    ImportError
        ``as_frame=True`` without pandas.
    """
    results = _read_results(path)
    if as_frame is False:
        return results
    try:
        import pandas as pd
    except ImportError:
        if as_frame:
            raise ImportError("read_results(as_frame=True) needs pandas: "
                              "pip install irdetect[pandas]") from None
        return results
    results.tables = {name: pd.DataFrame(table) for name, table in results.tables.items()}
    return results


#: what to do with a sequence given where a results file belongs
RUN_FIRST = "run `irdetect process` (or `track`) on it and give the results file it writes"


def _read_results(path) -> Results:
    check_input_file(path, "results file")
    try:
        with h5py.File(path, "r") as f:
            found = {}
            for name, obj in f.items():
                if isinstance(obj, h5py.Dataset) and obj.dtype.names is not None:
                    found[name] = obj[()]
            attrs = {k: _plain(v) for k, v in f.attrs.items()}
            sequence = isinstance(f.get("frames"), h5py.Dataset) and not set(found) - {"truth"}
    except OSError as exc:
        if Path(path).suffix.lower() in OTHER_SEQUENCE_SUFFIXES:
            raise InputError(f"a sequence, not a results file: {RUN_FIRST}", path) from None
        raise InputError(f"not a readable HDF5 file ({str(exc).splitlines()[0][:120]})",
                         path) from None
    if sequence:
        raise InputError(f"a sequence (it holds /frames), not a results file: {RUN_FIRST}",
                         path)
    results = Results(os.fspath(path), found, attrs)
    results.config          # a config attribute that is not JSON fails here, not later
    return results


def _plain(value):
    if isinstance(value, bytes):
        return value.decode()
    if isinstance(value, np.generic):
        return value.item()
    return value


def write_sequence(path: str | os.PathLike, frames, *, truth: np.ndarray | None = None,
                   attrs: dict | None = None, force: bool = False,
                   chunk_frames: int = 64, inputs=()) -> Path:
    """Write an image sequence to the HDF5 contract (``/frames``, optional ``/truth``).

    Parameters
    ----------
    frames : ndarray of shape (T, H, W), or an iterable of such blocks
        The frames; an iterable of blocks streams a long sequence without holding it.
    truth : structured ndarray, optional
        ``irdetect.tables.TRUTH`` rows (x = column, y = row, pixels).
    attrs : dict, optional
        Root attributes (e.g. ``frame_rate``).
    chunk_frames : int
        HDF5 chunk length along time; frames are chunked whole so windows read fast.
    inputs : iterable of path
        The files the frames come from: the output may be none of them.
    """
    out = AtomicH5(path, force=force, inputs=inputs)
    with out as f:
        blocks = [frames] if isinstance(frames, np.ndarray) else frames
        dset = None
        for block in blocks:
            block = np.asarray(block)
            if dset is None:
                dset = f.create_dataset("frames", shape=(0,) + block.shape[1:], dtype=block.dtype,
                                        maxshape=(None,) + block.shape[1:],
                                        chunks=(min(chunk_frames, max(1, len(block))),)
                                        + block.shape[1:])
            n = dset.shape[0]
            dset.resize((n + len(block),) + block.shape[1:])
            dset[n:] = block
            out.check()
        if dset is None:
            raise InputError("no frames to write", path)
        if truth is not None:
            f.create_dataset("truth", data=np.asarray(truth, dtype=tables.TRUTH))
        f.attrs["irdetect_version"] = __version__
        for key, value in (attrs or {}).items():
            f.attrs[key] = value
    return Path(path)


def read_point_annotations(path: str | os.PathLike, n_frames: int | None = None) -> np.ndarray:
    """Read a point annotation file: line i is ``x y`` of the target in frame i.

    This is the format of ``shared/data/real/*/truth.txt`` (x = column, y = row, 0-based).
    Blank lines and ``#`` comments are skipped; extra columns are ignored.

    Returns
    -------
    structured ndarray
        ``irdetect.tables.TRUTH`` rows with target 0 and amplitude NaN.

    Raises
    ------
    InputError
        Unreadable file, a line without two numbers, or a line count other than ``n_frames``.
    """
    rows = []
    check_input_file(path, "annotation file")
    try:
        with open(path, encoding="utf-8") as fh:
            for number, line in enumerate(fh, 1):
                text = line.split("#", 1)[0].strip()
                if not text:
                    continue
                parts = text.replace(",", " ").split()
                try:
                    x, y = float(parts[0]), float(parts[1])
                except (IndexError, ValueError):
                    raise InputError(f"line {number} is not 'x y': {line.strip()!r}",
                                     path) from None
                if not (np.isfinite(x) and np.isfinite(y)):
                    raise InputError(f"line {number} holds NaN or inf", path)
                rows.append((x, y))
    except FileNotFoundError:
        raise InputError("annotation file not found", path) from None
    except UnicodeDecodeError:
        raise InputError("annotation file is not text", path) from None
    if n_frames is not None and len(rows) != n_frames:
        raise InputError(f"{len(rows)} annotation lines for {n_frames} frames", path)
    xy = np.array(rows, dtype=float).reshape(-1, 2)
    return tables.from_columns(tables.TRUTH, frame=np.arange(len(rows)),
                               target=np.zeros(len(rows), int), x=xy[:, 0], y=xy[:, 1])
