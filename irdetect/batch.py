"""Batch processing: many sequences, one results file each, on local processes or Dask.

``run_batch(inputs, out_dir)`` expands the inputs (files, folders of sequences, globs),
skips those whose results already exist and match the input and the configuration
(resume), runs the rest through ``irdetect.pipeline.process_file`` on an executor, and
writes a summary table (CSV and JSON) beside the results. One input that fails is a row
of the summary with its error; it does not stop the others.

The executor is shared with anything that maps a function over many items (the Monte
Carlo benchmarks): ``map_tasks(fn, items, jobs=, scheduler=)`` runs ``fn`` in this
process (``jobs=1``), on ``jobs`` local processes, or on a Dask distributed cluster
(``scheduler`` = its address, or the ``IRDETECT_SCHEDULER`` environment variable).
See ``docs/batch.md``.
"""

from __future__ import annotations

import csv
import ctypes
import glob
import hashlib
import io
import json
import logging
import multiprocessing
import os
import sys
import time
import uuid
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

from irdetect import __version__
from irdetect.config import ProcessConfig, to_json
from irdetect.errors import InputError

log = logging.getLogger(__name__)

#: environment variable naming the Dask scheduler when ``scheduler`` is not given
SCHEDULER_ENV = "IRDETECT_SCHEDULER"
#: results files are ``<input name>`` + this suffix in the output folder
RESULTS_SUFFIX = ".irdetect.h5"
#: the summary table is ``<out_dir>/irdetect-summary.csv`` and ``.json``
SUMMARY_NAME = "irdetect-summary"
#: root attributes of a results file that identify its input (the resume fingerprint)
FINGERPRINT_ATTRS = ("source_path", "source_size", "source_mtime_ns", "source_digest",
                     "source_dataset")
#: bytes hashed at each end of an input file, and the size of each sample in between
_HEAD = 1 << 16
_SAMPLE = 1 << 12
_N_SAMPLES = 16
_GLOB_CHARS = set("*?[")
#: seconds to wait for the Dask scheduler to answer
CONNECT_TIMEOUT = 10.0
#: glibc mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_WORKER_TUNED = False


# --- the summary table ---------------------------------------------------------------

@dataclass
class BatchRow:
    """One input of a batch: what happened to it.

    ``status`` is ``ok`` (processed now), ``skipped`` (results exist and match),
    ``failed`` (the input or its results file is at fault; ``error`` says why) or
    ``lost`` (the executor could not run it, e.g. its Dask worker died too often).
    Counts are None when unknown (failed, lost); ``seconds`` is None for skipped inputs.
    """

    input: str
    output: str
    frames: int | None = None
    detections: int | None = None
    tracks: int | None = None
    seconds: float | None = None
    status: str = "failed"
    error: str = ""


COLUMNS = tuple(f.name for f in fields(BatchRow))


@dataclass
class BatchReport:
    """The outcome of ``run_batch``: one row per input in input order, and the summary files."""

    rows: list[BatchRow]
    csv_path: Path
    json_path: Path
    executor: str = "serial"
    seconds: float = 0.0

    @property
    def failed(self) -> list[BatchRow]:
        """Rows whose status is ``failed`` or ``lost``."""
        return [r for r in self.rows if r.status in ("failed", "lost")]

    def counts(self) -> dict[str, int]:
        """Number of rows per status."""
        out = {s: 0 for s in ("ok", "skipped", "failed", "lost")}
        for r in self.rows:
            out[r.status] = out.get(r.status, 0) + 1
        return out


@dataclass
class Job:
    """One input to process: the task ``_process_one`` receives (picklable)."""

    input: str
    output: str
    config: ProcessConfig
    dataset: str | None = None
    force: bool = False
    attrs: dict = field(default_factory=dict)


# --- inputs ---------------------------------------------------------------------------

def _sequence_suffixes() -> set[str]:
    from irdetect.io.sources import HDF5_SUFFIXES, MAT_SUFFIXES, VIDEO_SUFFIXES
    return set(HDF5_SUFFIXES) | set(VIDEO_SUFFIXES) | set(MAT_SUFFIXES) | {".npy"}


def is_image_folder(path: Path) -> bool:
    """True when the folder is one image sequence (its images, or a recording folder's
    ``frames/``), not a folder of sequences."""
    from irdetect.io.sources import folder_images
    return bool(folder_images(path))


def _is_results(path: Path) -> bool:
    return path.name.endswith(RESULTS_SUFFIX)


def expand_inputs(inputs: Iterable[str | os.PathLike]) -> list[Path]:
    """Turn command-line inputs into a list of sequences, in order, without duplicates.

    Parameters
    ----------
    inputs : iterable of str or os.PathLike
        Each is a sequence file (HDF5, video, ``.npy``, ``.mat``), a folder of images (one
        sequence), a folder of sequences (its sequence files and image subfolders, not
        recursive), or a glob pattern (``data/*.h5``, ``runs/**/*.h5``) for when the shell
        does not expand it.

    Returns
    -------
    list of Path
        The sequences. Results files (``*.irdetect.h5``) and hidden files are never
        inputs, so an output folder inside the input folder is harmless.

    Raises
    ------
    InputError
        A path that does not exist, a pattern that matches nothing, a folder that holds
        no sequence.
    """
    found: list[Path] = []
    for arg in inputs:
        text = os.fspath(arg)
        path = Path(text)
        if path.exists():
            matches = [path]
        elif _GLOB_CHARS & set(text):
            matches = [Path(m) for m in sorted(glob.glob(text, recursive=True))]
            if not matches:
                raise InputError("no file matches this pattern", text)
        else:
            raise InputError("file not found", text)
        for m in matches:
            if m.is_dir() and not is_image_folder(m):
                members = _folder_sequences(m)
                if not members and len(matches) == 1:
                    raise InputError("folder holds no sequence (HDF5, video, .npy, .mat or a "
                                     "folder "
                                     "of images)", m)
                found.extend(members)
            elif not _is_results(m):
                found.append(m)
            else:
                log.debug("skipping results file %s", m)
    unique, seen = [], set()
    for p in found:
        key = p.resolve()
        if key not in seen:
            seen.add(key)
            unique.append(p)
    return unique


def _folder_sequences(folder: Path) -> list[Path]:
    from irdetect.io.sources import natural_key
    suffixes = _sequence_suffixes()
    out = []
    for p in sorted(folder.iterdir(), key=lambda q: natural_key(q.name)):
        if p.name.startswith(".") or _is_results(p):
            continue
        if (p.is_file() and p.suffix.lower() in suffixes) or (p.is_dir() and is_image_folder(p)):
            out.append(p)
    return out


def output_name(path: str | os.PathLike) -> str:
    """``<input name>.irdetect.h5``: the stem of a file, the name of a folder."""
    path = Path(path)
    name = path.name if path.is_dir() else path.stem
    return name + RESULTS_SUFFIX


# --- resume ---------------------------------------------------------------------------

def fingerprint(path: str | os.PathLike, dataset: str | None = None) -> dict:
    """Root attributes that identify an input, stored in its results file.

    Parameters
    ----------
    path : str or os.PathLike
        A sequence file or a folder of images.
    dataset : str, optional
        The HDF5 dataset path used (part of the identity).

    Returns
    -------
    dict
        ``source_path`` (absolute), ``source_size`` (bytes; a folder: sum of its files),
        ``source_mtime_ns`` (newest), ``source_digest`` (BLAKE2b of the size, the first and
        last 64 KiB and 16 evenly spaced 4 KiB samples; a folder: of every file's name, size,
        first and last 4 KiB) and ``source_dataset`` ('' for the default).

    Notes
    -----
    Cheap by design: about 200 KiB are read per file whatever its size, so checking
    thousands of inputs on a network file system takes seconds. An in-place edit that
    keeps the size and touches none of the sampled bytes goes unnoticed; use ``--force``
    after such edits.
    """
    path = Path(path)
    h = hashlib.blake2b(digest_size=16)
    try:
        if path.is_dir():
            files = sorted((p for p in path.iterdir() if p.is_file()
                            and not p.name.startswith(".")), key=lambda p: p.name)
            size, mtime = 0, 0
            for p in files:
                st = p.stat()
                size += st.st_size
                mtime = max(mtime, st.st_mtime_ns)
                h.update(p.name.encode() + b"\0" + str(st.st_size).encode() + b"\0")
                _digest_file(h, p, st.st_size, head=_SAMPLE, samples=0)
        else:
            st = path.stat()
            size, mtime = st.st_size, st.st_mtime_ns
            h.update(str(size).encode() + b"\0")
            _digest_file(h, path, size, head=_HEAD, samples=_N_SAMPLES)
    except OSError as exc:
        raise InputError(f"cannot read ({exc.strerror or exc})", path) from None
    return {"source_path": os.fspath(path.resolve()), "source_size": int(size),
            "source_mtime_ns": int(mtime), "source_digest": h.hexdigest(),
            "source_dataset": dataset or ""}


def _digest_file(h, path: Path, size: int, *, head: int, samples: int) -> None:
    with open(path, "rb") as fh:
        if size <= 2 * head + samples * _SAMPLE:
            h.update(fh.read())
            return
        h.update(fh.read(head))
        for k in range(1, samples + 1):
            fh.seek(head + (size - 2 * head) * k // (samples + 1))
            h.update(fh.read(_SAMPLE))
        fh.seek(size - head)
        h.update(fh.read(head))


def check_existing(output: str | os.PathLike, attrs: dict, config_json: str) -> BatchRow | str:
    """Compare an existing results file with the input and config it should come from.

    Returns
    -------
    BatchRow or str
        A ``skipped`` row with the counts stored in the file when the size, digest and
        dataset of the input and the resolved configuration match; otherwise the reason
        they do not (a string).
    """
    import h5py

    try:
        with h5py.File(output, "r") as f:
            stored = {k: f.attrs.get(k) for k in (*FINGERPRINT_ATTRS, "config", "n_frames")}
            stored = {k: v.decode() if isinstance(v, bytes) else v for k, v in stored.items()}
            n_det = f["detections"].shape[0] if "detections" in f else None
            n_trk = f["tracks"].shape[0] if "tracks" in f else None
    except OSError:
        return "it is not a readable results file"
    if stored["source_digest"] is None:
        return "it holds no input fingerprint (not written by a batch run)"
    for key in ("source_size", "source_digest", "source_dataset"):
        if stored[key] != attrs[key]:
            return f"it was made from a different input ({key} differs)"
    if stored["config"] != config_json:
        return "it was made with a different configuration"
    if n_det is None or n_trk is None:
        return "it lacks /detections or /tracks"
    return BatchRow(input="", output=os.fspath(output), frames=int(stored["n_frames"]),
                    detections=int(n_det), tracks=int(n_trk), status="skipped")


# --- the batch ------------------------------------------------------------------------

def run_batch(inputs: Iterable[str | os.PathLike], out_dir: str | os.PathLike,
              config: ProcessConfig | None = None, *, dataset: str | None = None,
              force: bool = False, jobs: int | None = None, scheduler=None,
              progress: bool = False) -> BatchReport:
    """Process many sequences, one results file each, and write a summary table.

    Parameters
    ----------
    inputs : iterable of str or os.PathLike
        Files, folders of sequences, folders of images, glob patterns (``expand_inputs``).
    out_dir : str or os.PathLike
        Folder of the results (created if missing): ``<input name>.irdetect.h5`` per
        input, plus ``irdetect-summary.csv`` and ``irdetect-summary.json``.
    config : ProcessConfig, optional
        Stage parameters, the same for every input.
    dataset : str, optional
        HDF5 dataset path of the frames in every HDF5 input.
    force : bool
        Redo inputs whose results exist (otherwise matching results are skipped and
        results made from another input or config are reported as failed).
    jobs : int, optional
        Local worker processes (default ``os.cpu_count()``; 1 runs in this process).
    scheduler : str or distributed.Client, optional
        Dask scheduler address (``tcp://host:8786``), a scheduler JSON file, or a
        connected client; default the ``IRDETECT_SCHEDULER`` environment variable. When
        set, ``jobs`` is ignored.
    progress : bool
        tqdm bar over sequences.

    Returns
    -------
    BatchReport
        Rows in input order; ``report.failed`` lists what went wrong.

    Raises
    ------
    InputError
        Bad inputs (``expand_inputs``), two inputs with the same results name, an output
        folder that cannot be made, an unreachable scheduler.
    """
    t0 = time.perf_counter()
    config = config or ProcessConfig()
    jobs = _check_jobs(jobs)
    paths = expand_inputs(inputs)
    if not paths:
        raise InputError("no input sequences")
    out_dir = Path(out_dir)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create the output folder ({exc.strerror or exc})",
                         out_dir) from None
    outputs = [out_dir / output_name(p) for p in paths]
    _check_collisions(paths, outputs)

    config_json = to_json(config)
    rows: list[BatchRow | None] = [None] * len(paths)
    todo: list[tuple[int, Job]] = []
    for i, (path, output) in enumerate(zip(paths, outputs)):
        try:
            attrs = fingerprint(path, dataset)
        except InputError as exc:
            rows[i] = BatchRow(os.fspath(path), os.fspath(output), error=str(exc))
            log.error("%s", exc)
            continue
        if output.exists() and not force:
            found = check_existing(output, attrs, config_json)
            if isinstance(found, BatchRow):
                found.input = os.fspath(path)
                rows[i] = found
            else:
                rows[i] = BatchRow(os.fspath(path), os.fspath(output),
                                   error=f"results exist but {found}; use --force to redo")
                log.error("%s: %s", path, rows[i].error)
            continue
        # absolute paths: a Dask worker runs in another folder, maybe on another machine
        todo.append((i, Job(os.path.abspath(path), os.path.abspath(output), config, dataset,
                            force, attrs)))
    skipped = sum(r is not None and r.status == "skipped" for r in rows)
    if skipped:
        log.info("%d of %d inputs already done (skipped; --force redoes them)", skipped,
                 len(paths))

    executor = _executor_name(jobs, scheduler, len(todo))
    bar = _bar(len(todo), progress, "sequences")
    try:
        outcomes = imap_tasks(_process_one, [job for _, job in todo], jobs=jobs,
                              scheduler=scheduler)
        for k, value, error in outcomes:
            i = todo[k][0]
            if error is None:
                rows[i] = value
                value.input, value.output = os.fspath(paths[i]), os.fspath(outputs[i])
            else:       # the executor lost the task (worker died, pool broke, cancelled)
                rows[i] = BatchRow(os.fspath(paths[i]), os.fspath(outputs[i]), status="lost",
                                   error=_describe(error))
            if rows[i].status != "ok":
                log.error("%s: %s", paths[i], rows[i].error)
            if bar is not None:
                bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    for _, job in todo:     # every task has ended: what is left was a dead worker's
        _remove_temporaries(Path(job.output))
    report = BatchReport(rows, out_dir / f"{SUMMARY_NAME}.csv", out_dir / f"{SUMMARY_NAME}.json",
                         executor=executor, seconds=time.perf_counter() - t0)
    write_summary(report)
    return report


def _process_one(job: Job) -> BatchRow:
    """Run one input; any error becomes a ``failed`` row (the task itself never raises)."""
    from irdetect.pipeline import process_file

    _tune_dask_worker()
    t0 = time.perf_counter()
    try:
        s = process_file(job.input, job.output, job.config, dataset=job.dataset,
                         force=job.force, attrs=job.attrs)
    except Exception as exc:      # noqa: BLE001 -- reported in the summary, batch goes on
        return BatchRow(job.input, job.output, seconds=time.perf_counter() - t0,
                        status="failed", error=_describe(exc))
    return BatchRow(job.input, job.output, frames=int(s["frames"]),
                    detections=int(s["detections"]), tracks=int(s["tracks"]),
                    seconds=float(s["seconds"]), status="ok")


def _tune_dask_worker() -> None:
    """On a Dask worker, once: one OpenCV thread, and glibc's default malloc thresholds back.

    Dask runs one task per worker thread and the docs start one single-threaded worker
    per core, so OpenCV's own pool (a thread per core in every worker) would only
    oversubscribe the cores. Dask's nanny starts workers with ``MALLOC_TRIM_THRESHOLD_=65536``,
    which also pins the mmap threshold at 128 KiB: every frame-sized array is then a fresh
    mmap, zero-filled page by page, and the pipeline spends as much time in the kernel as
    in numpy (a 256 x 256 x 240 sequence: 0.4 s system time instead of 0.05 s, twice the wall
    time). Raising both thresholds (32 MiB mmap, 64 MiB trim) restores the speed of a plain
    process; memory above 64 MiB is still given back to the system.
    """
    global _WORKER_TUNED
    distributed = sys.modules.get("distributed")     # never imported: not on a worker
    if _WORKER_TUNED or distributed is None:
        return
    try:
        distributed.get_worker()
    except ValueError:
        return
    import cv2
    cv2.setNumThreads(1)
    if os.environ.get("MALLOC_TRIM_THRESHOLD_") and sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL("libc.so.6")
            libc.mallopt(_M_MMAP_THRESHOLD, 32 << 20)
            libc.mallopt(_M_TRIM_THRESHOLD, 64 << 20)
        except (OSError, AttributeError):        # not glibc
            pass
    _WORKER_TUNED = True


def _remove_temporaries(output: Path) -> None:
    """Delete the temporary and lock files a killed worker left beside ``output``
    (``irdetect.io.atomic.OutputLock`` removes them once it holds the lock; a live
    writer's are left alone)."""
    from irdetect.io.atomic import OutputLock

    try:
        with OutputLock(output):
            pass
    except InputError as exc:      # another run writes it now, or the folder is read-only
        log.debug("left %s's temporaries: %s", output, exc)


def _describe(exc: BaseException) -> str:
    if isinstance(exc, InputError):
        text = str(exc)
        # the path is in the row already; keep the message
        return text
    name = type(exc).__name__
    text = str(exc).strip().splitlines()
    return f"{name}: {text[0]}" if text else name


def _check_jobs(jobs) -> int:
    if jobs is None:
        return os.cpu_count() or 1
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise ValueError(f"jobs must be an integer >= 1, got {jobs!r}")
    return jobs


def _check_collisions(paths: list[Path], outputs: list[Path]) -> None:
    seen: dict[Path, Path] = {}
    for p, o in zip(paths, outputs):
        if o in seen:
            # NAME/frames of several recordings (a recording folder: its frames and
            # truth.txt): the recording folders themselves are named apart
            hint = (f", or give the recording folders holding them ({seen[o].parent.name}, "
                    f"{p.parent.name}) instead" if p.is_dir() and p.name == seen[o].name
                    and p.parent.name != seen[o].parent.name else "")
            raise InputError(f"{seen[o]} and {p} would both write {o.name}; "
                             f"process them into different --out-dir folders{hint}", p)
        seen[o] = p


# --- the summary ----------------------------------------------------------------------

def write_summary(report: BatchReport) -> tuple[Path, Path]:
    """Write the rows as CSV and JSON (atomically, replacing the previous summary)."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(COLUMNS)
    for r in report.rows:
        writer.writerow(["" if v is None else (f"{v:.3f}" if isinstance(v, float) else v)
                         for v in asdict(r).values()])
    doc = {"irdetect_version": __version__, "executor": report.executor,
           "seconds": round(report.seconds, 3), "counts": report.counts(),
           "rows": [asdict(r) for r in report.rows]}
    _write_text(report.csv_path, buf.getvalue())
    _write_text(report.json_path, json.dumps(doc, indent=1) + "\n")
    return report.csv_path, report.json_path


def _write_text(path: Path, text: str) -> None:
    # not mkstemp: its 0600 mode would hide the summary from the rest of a shared cluster
    for old in path.parent.glob(f".{glob.escape(path.name)}.*.tmp"):
        pid = old.name[len(path.name) + 2:].split(".")[0]
        if pid.isdigit() and not _alive(int(pid)):      # a batch killed while it wrote
            old.unlink(missing_ok=True)
    tmp = path.parent / f".{path.name}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp"
    try:
        with open(tmp, "x", encoding="utf-8") as fh:
            fh.write(text)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def format_summary(report: BatchReport, *, limit: int = 40) -> str:
    """The summary as a text table: up to ``limit`` rows (every failure), then totals."""
    rows = report.rows
    if len(rows) > limit:
        bad = [r for r in rows if r.status in ("failed", "lost")]
        rest = [r for r in rows if r.status not in ("failed", "lost")]
        rows = bad + rest[:max(0, limit - len(bad))]
    cells = [["input", "frames", "detections", "tracks", "seconds", "status", "error"]]
    for r in rows:
        cells.append([Path(r.input).name, _cell(r.frames), _cell(r.detections), _cell(r.tracks),
                      "" if r.seconds is None else f"{r.seconds:.2f}", r.status,
                      r.error[:100]])
    widths = [max(len(c[j]) for c in cells) for j in range(len(cells[0]))]
    lines = ["  ".join(c.ljust(w) if j in (0, 5, 6) else c.rjust(w)
                       for j, (c, w) in enumerate(zip(cell, widths))).rstrip()
             for cell in cells]
    if len(rows) < len(report.rows):
        lines.append(f"... {len(report.rows) - len(rows)} more rows in {report.csv_path}")
    counts = report.counts()
    lines.append(f"{len(report.rows)} inputs: " + ", ".join(f"{n} {s}" for s, n in counts.items()
                                                           if n)
                 + f" in {report.seconds:.1f} s ({report.executor}); summary: {report.csv_path}")
    return "\n".join(lines)


def _cell(value) -> str:
    return "" if value is None else str(value)


# --- executors ------------------------------------------------------------------------

def resolve_scheduler(scheduler=None):
    """The scheduler to use: the argument, else ``$IRDETECT_SCHEDULER``, else None (local)."""
    if scheduler is None or scheduler == "":
        scheduler = os.environ.get(SCHEDULER_ENV) or None
    return scheduler


def _executor_name(jobs: int, scheduler, n_items: int) -> str:
    scheduler = resolve_scheduler(scheduler)
    if scheduler is not None:
        rpc = getattr(scheduler, "scheduler", None)       # a distributed.Client
        return f"dask {rpc.address if rpc is not None else scheduler}"
    if jobs == 1 or n_items <= 1:
        return "serial"
    return f"{min(jobs, n_items)} local processes"


def imap_tasks(fn: Callable[[Any], Any], items: Iterable, *, jobs: int | None = None,
               scheduler=None) -> Iterator[tuple[int, Any, BaseException | None]]:
    """Run ``fn(item)`` for every item; yield ``(index, result, error)`` as each finishes.

    Parameters
    ----------
    fn : callable
        A module-level function (pickled to the workers; a function defined in a script
        works on Dask, and on local processes when the script guards its main code with
        ``if __name__ == "__main__":``).
    items : iterable
        Picklable arguments, one task each.
    jobs : int, optional
        Local processes (default ``os.cpu_count()``); 1 runs in this process, in order.
    scheduler : str or distributed.Client, optional
        Dask scheduler address or scheduler JSON file, or a client; default
        ``$IRDETECT_SCHEDULER``. Takes precedence over ``jobs``.

    Yields
    ------
    tuple
        ``(index into items, fn's return value or None, the exception or None)``, in
        completion order. An exception raised by ``fn``, a dead local process or a task
        Dask gave up on (``KilledWorker``: its worker died ``allowed-failures`` + 1 times)
        is yielded as the error of that item; the other items go on.
    """
    items = list(items)
    jobs = _check_jobs(jobs)
    scheduler = resolve_scheduler(scheduler)
    if not items:
        return
    if scheduler is not None:
        yield from _imap_dask(fn, items, scheduler)
    elif jobs == 1 or len(items) == 1:
        for i, item in enumerate(items):
            try:
                yield i, fn(item), None
            except Exception as exc:     # noqa: BLE001 -- handed to the caller
                yield i, None, exc
    else:
        yield from _imap_processes(fn, items, min(jobs, len(items)))


def map_tasks(fn: Callable[[Any], Any], items: Iterable, *, jobs: int | None = None,
              scheduler=None, progress: bool = False, desc: str = "tasks") -> list:
    """``[fn(item) for item in items]`` on the batch executor, results in item order.

    The executor of ``irdetect process`` for anything else (Monte Carlo benchmarks):
    one option moves a study from this process to local processes to a Dask cluster.

    Parameters
    ----------
    fn, items, jobs, scheduler
        As in ``imap_tasks``.
    progress : bool
        tqdm bar over items.
    desc : str
        Label of the bar.

    Returns
    -------
    list
        ``fn(item)`` for each item, in the order of ``items``.

    Raises
    ------
    Exception
        The first error of any item (after the others finished), with a note naming the
        item's index; use ``imap_tasks`` to keep going past failures.

    Examples
    --------
    >>> map_tasks(abs, [-1, 2, -3], jobs=1)
    [1, 2, 3]
    """
    items = list(items)
    out: list = [None] * len(items)
    first: tuple[int, BaseException] | None = None
    bar = _bar(len(items), progress, desc)
    try:
        for i, value, error in imap_tasks(fn, items, jobs=jobs, scheduler=scheduler):
            if error is not None and (first is None or i < first[0]):
                first = (i, error)
            out[i] = value
            if bar is not None:
                bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    if first is not None:
        first[1].add_note(f"(task {first[0]} of {len(items)}: {items[first[0]]!r})")
        raise first[1]
    return out


def _mp_context():
    methods = multiprocessing.get_all_start_methods()
    # not fork: OpenCV's thread pool does not survive fork in a process that used it
    return multiprocessing.get_context("forkserver" if "forkserver" in methods else "spawn")


def _init_worker(threads: int, parent: int | None = None) -> None:
    import cv2
    cv2.setNumThreads(threads)
    if parent is not None:
        import threading
        watch = threading.Thread(target=_watch_parent, args=(parent,), daemon=True,
                                 name=WATCH_THREAD)
        watch.start()


#: the name of the worker's thread that watches the batch's process (it allocates nothing,
#: so ``irdetect.errors`` does not count it as a thread another allocation could hurt)
WATCH_THREAD = "irdetect-parent-watch"


def _watch_parent(pid: int, every: float = 0.2) -> None:
    """End this worker when the batch's process ``pid`` is gone (killed with SIGKILL, it
    cannot tell its pool: the workers, children of the forkserver, waited forever on the
    task queue, and kept the forkserver and the resource tracker alive with them). A
    write in progress leaves its temporary and lock, which the next run removes."""
    while _alive(pid):
        time.sleep(every)
    os._exit(1)


def _alive(pid: int) -> bool:
    """Whether process ``pid`` runs (a zombie, dead but not yet reaped, does not)."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            return fh.read().rsplit(b")", 1)[1].split()[0] != b"Z"
    except FileNotFoundError:
        return False
    except OSError:                            # no /proc: ask the kernel
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return False
        except PermissionError:
            pass
        return True


def _imap_processes(fn, items, workers):
    threads = max(1, (os.cpu_count() or 1) // workers)
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=_mp_context(),
                               initializer=_init_worker, initargs=(threads, os.getpid()))
    try:
        futures = {pool.submit(fn, item): i for i, item in enumerate(items)}
        for future in as_completed(futures):
            try:
                yield futures[future], future.result(), None
            except Exception as exc:     # noqa: BLE001 -- includes BrokenProcessPool
                yield futures[future], None, exc
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _import_distributed():
    try:
        import distributed
    except ImportError:
        raise InputError("--scheduler needs Dask distributed: pip install "
                         "'irdetect[distributed]' (or pip install 'dask[distributed]')") from None
    return distributed


def connect(scheduler):
    """A ``distributed.Client`` for an address or scheduler JSON file (or the client given).

    Raises
    ------
    InputError
        Dask distributed is not installed, or the scheduler cannot be reached.
    """
    distributed = _import_distributed()
    if isinstance(scheduler, distributed.Client):
        return scheduler
    text = os.fspath(scheduler)
    try:
        if text.endswith(".json") and Path(text).is_file():
            return distributed.Client(scheduler_file=text, set_as_default=False, timeout=CONNECT_TIMEOUT)
        return distributed.Client(text, set_as_default=False, timeout=CONNECT_TIMEOUT)
    except (OSError, TimeoutError, ValueError) as exc:
        raise InputError(f"cannot reach the Dask scheduler ({_describe(exc)})", text) from None


def _imap_dask(fn, items, scheduler):
    distributed = _import_distributed()
    client = connect(scheduler)
    own = client is not scheduler
    futures = []
    try:
        futures = client.map(fn, items, pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        for future in distributed.as_completed(futures, loop=client.loop):
            i = index[future.key]
            try:
                yield i, future.result(), None
            except Exception as exc:     # noqa: BLE001 -- KilledWorker, task errors
                reason = getattr(exc, "reason", None)
                if future.cancelled() and reason:     # e.g. the scheduler went away
                    exc = RuntimeError(f"cancelled by Dask ({reason})")
                yield i, None, exc
            future.release()
    finally:
        if futures:
            client.cancel([f for f in futures if not f.done()])
        if own:
            _close_quietly(client)


def _close_quietly(client) -> None:
    """Close a client we opened, even when its scheduler is already gone."""
    try:
        client.close(timeout=CONNECT_TIMEOUT)
    except Exception:     # noqa: BLE001 -- nothing to do about a client that will not close
        log.debug("the Dask client did not close cleanly", exc_info=True)


def _bar(total: int, progress: bool, unit: str):
    if not progress:
        return None
    from tqdm import tqdm
    return tqdm(total=total, unit=unit[:-1] if unit.endswith("s") else unit, desc=unit,
                leave=False)
