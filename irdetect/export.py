"""Results in the formats other tools read: CSV tables, MOTChallenge text, JSON, MATLAB.

``export_results(results, folder, fmt)`` writes, atomically and without overwriting
unless ``force``:

* ``csv``: ``detections.csv``, ``tracks.csv`` and ``track_positions.csv`` (one row per
  track per frame of its span: ``frame``, ``track_id``, ``x``, ``y``), one header line of
  field names each;
* ``mot``: ``tracks_mot.txt``, the MOTChallenge text format that TrackEval and
  py-motmetrics read: ``frame, id, bb_left, bb_top, bb_width, bb_height, conf, x, y, z``
  per track per frame;
* ``json``: ``results.json``, the root attributes, the configuration and every table as
  a list of records (NaN written as null);
* ``mat``: ``results.mat`` (MATLAB, ``load results.mat``), every table and
  ``track_positions`` as a struct of column vectors (``detections.x``), ``attrs`` as a
  struct and ``config`` as JSON text; values as in the results file (frames and pixels
  counted from 0, x = column, y = row: pixel (x, y) of frame f is ``seq(y+1, x+1, f+1)``).

Track positions are where each track's line puts it in each frame of its span
(``irdetect.initiate.track_positions``; a scene track follows the camera of ``/camera``);
the results of ``irdetect track`` give them per frame in ``/track_points``.
"""

from __future__ import annotations

import csv
import json
import math
import os
from pathlib import Path

import numpy as np

from irdetect import tables
from irdetect.errors import InputError
from irdetect.io.atomic import atomic_output, check_output_path

FORMATS = ("csv", "mot", "json", "mat")

#: rows of ``track_positions``: where a track is in one frame (x = column, y = row, px)
POSITION = np.dtype([("frame", "<i8"), ("track_id", "<i8"), ("x", "<f8"), ("y", "<f8"),
                     ("score", "<f8")])

#: side of the square box a point track gets in the MOT file (px)
MOT_BOX = 5.0

FILES = {"csv": ("detections.csv", "tracks.csv", "track_positions.csv"),
         "mot": ("tracks_mot.txt",), "json": ("results.json",), "mat": ("results.mat",)}


def track_positions(results) -> np.ndarray:
    """One row per track per frame of its span: where the track is.

    Parameters
    ----------
    results : irdetect.io.Results
        Read with ``irdetect.io.read_results`` (structured arrays).

    Returns
    -------
    structured ndarray of dtype ``POSITION``
        ``frame`` (from 0), ``track_id``, ``x``, ``y`` (px, x = column, y = row) and the
        track's ``score``; sorted by frame, then track. From ``/track_points`` when the
        results hold them (``irdetect track``, score NaN), else from the lines of
        ``/tracks`` over ``frame_start`` .. ``frame_end``.
    """
    if "track_points" in results:
        pts = np.asarray(results["track_points"])
        out = np.zeros(len(pts), POSITION)
        for name in ("frame", "track_id", "x", "y"):
            out[name] = pts[name]
        out["score"] = np.nan
        return np.sort(out, order=["frame", "track_id"])
    if "tracks" not in results:
        return np.zeros(0, POSITION)
    from irdetect.initiate import track_positions as line_positions

    tracks = np.asarray(results["tracks"])
    tracks = tracks[np.isfinite(tracks["x0"]) & np.isfinite(tracks["vx"])]
    camera = results["camera"] if "camera" in results and len(results["camera"]) else None
    parts = []
    for row in tracks:
        frames = np.arange(int(row["frame_start"]), int(row["frame_end"]) + 1)
        pos = line_positions(row.reshape(1), frames, camera)[0]          # (m, 2)
        part = np.zeros(len(frames), POSITION)
        part["frame"], part["track_id"], part["score"] = frames, row["track_id"], row["score"]
        part["x"], part["y"] = pos[:, 0], pos[:, 1]
        parts.append(part)
    if not parts:
        return np.zeros(0, POSITION)
    return np.sort(np.concatenate(parts), order=["frame", "track_id"])


def mot_rows(positions: np.ndarray, *, box: float = MOT_BOX) -> np.ndarray:
    """MOTChallenge rows of track positions.

    Parameters
    ----------
    positions : structured ndarray of dtype ``POSITION``
    box : float
        Side of the square box centred on each point (px).

    Returns
    -------
    ndarray of shape (N, 10)
        ``frame, id, bb_left, bb_top, bb_width, bb_height, conf, x, y, z``. MOT counts
        frames and pixels from 1, irdetect from 0: frame + 1, and the box's top-left
        corner at (x + 1 - box / 2, y + 1 - box / 2). ``conf`` is the track's score (1
        when it has none); x, y, z are -1 (no world coordinates), as MOT 2-D files have.
    """
    if not box > 0:
        raise ValueError(f"box must be > 0, got {box}")
    p = np.asarray(positions)
    conf = np.where(np.isfinite(p["score"]), p["score"], 1.0)
    minus = -np.ones(len(p))
    return np.column_stack([p["frame"] + 1, p["track_id"], p["x"] + 1 - box / 2,
                            p["y"] + 1 - box / 2, np.full(len(p), box), np.full(len(p), box),
                            conf, minus, minus, minus])


def export_files(folder: str | os.PathLike, fmt: str) -> list[Path]:
    """The files ``export_results`` writes for ``fmt`` in ``folder``."""
    if fmt not in FORMATS:
        raise InputError(f"unknown export format {fmt!r} (use {', '.join(FORMATS)})")
    return [Path(folder) / name for name in FILES[fmt]]


def export_results(results, folder: str | os.PathLike, fmt: str, *, box: float = MOT_BOX,
                   force: bool = False) -> list[Path]:
    """Write a results file's tables in ``fmt`` (csv, mot, json or mat) into ``folder``.

    Parameters
    ----------
    results : irdetect.io.Results
        Read with ``irdetect.io.read_results`` (structured arrays).
    folder : str or os.PathLike
        Output folder; created when missing (its parent must exist).
    fmt : {"csv", "mot", "json", "mat"}
    box : float
        Side of the MOT boxes (px), see ``mot_rows``.
    force : bool
        Replace existing files; without it an existing file stops the export before
        anything is written.

    Returns
    -------
    list of Path
        The files written (``export_files``).

    Raises
    ------
    InputError
        Unknown format, a missing parent folder, an existing file without ``force``, or
        csv / mot of results without detections or image tracks.
    """
    paths = export_files(folder, fmt)
    from irdetect.metrics.initiation import scan_tracks_of

    scans = scan_tracks_of(results, warn=False) is not None
    if fmt in ("csv", "mot") and (scans or not any(
            name in results for name in ("detections", "tracks", "track_points"))):
        raise InputError("holds no detections or image tracks (results of irdetect "
                         "initiate on scans go out with --format json or mat)", results.path)
    folder = Path(folder)
    if not folder.is_dir():
        check_output_path(folder, force=False)                 # the parent must exist
        folder.mkdir()
    inputs = (results.path,)
    for path in paths:
        check_output_path(path, force, inputs)
    # scan tracks are lines in the scans' (x, y), not image tracks over frames
    positions = np.zeros(0, POSITION) if scans else track_positions(results)
    if fmt == "csv":
        for path, table in zip(paths, (_table(results, "detections"),
                                       _table(results, "tracks"), positions)):
            _write_csv(path, table, force=force, inputs=inputs)
    elif fmt == "mot":
        with atomic_output(paths[0], force=force, inputs=inputs, suffix=paths[0].suffix) as tmp:
            np.savetxt(tmp, mot_rows(positions, box=box), delimiter=",",
                       fmt=["%d", "%d", "%.3f", "%.3f", "%g", "%g", "%.6g", "%d", "%d", "%d"])
    elif fmt == "mat":
        from scipy.io import savemat

        doc = {name: _columns(t) for name, t in results.tables.items()}
        doc.update(track_positions=_columns(positions),
                   config=_plain_attr(results.attrs.get("config", "")),
                   attrs={k: _plain_attr(v) for k, v in results.attrs.items()
                          if k != "config"})
        with atomic_output(paths[0], force=force, inputs=inputs, suffix=paths[0].suffix) as tmp:
            savemat(tmp, doc, do_compression=True, oned_as="column")
    else:
        doc = {"attrs": {k: _finite(v) for k, v in results.attrs.items() if k != "config"},
               "config": results.config,
               "tables": {name: _records(t) for name, t in results.tables.items()},
               "track_positions": _records(positions)}
        with atomic_output(paths[0], force=force, inputs=inputs, suffix=paths[0].suffix) as tmp:
            Path(tmp).write_text(json.dumps(doc, default=_plain, allow_nan=False) + "\n",
                                 encoding="utf-8")
    return paths


def _table(results, name):
    return np.asarray(results[name]) if name in results else tables.empty(name)


def _write_csv(path, table: np.ndarray, *, force: bool, inputs=()) -> None:
    names = table.dtype.names
    with atomic_output(path, force=force, inputs=inputs, suffix=".csv") as tmp, \
            open(tmp, "w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh)
        writer.writerow(names)
        columns = [table[n].tolist() for n in names]
        writer.writerows(zip(*columns))


def _records(table: np.ndarray) -> list[dict]:
    names = table.dtype.names or ()
    columns = {n: [_finite(v) for v in table[n].tolist()] for n in names}
    return [dict(zip(names, values)) for values in zip(*columns.values())]


def _columns(table: np.ndarray) -> dict:
    """A table as MATLAB sees a struct of column vectors: field -> 1-D array."""
    return {n: np.ascontiguousarray(table[n]) for n in table.dtype.names or ()}


def _plain_attr(value):
    """An HDF5 attribute as savemat takes it (text as str, not bytes)."""
    return value.decode() if isinstance(value, bytes) else value


def _finite(value):
    return None if isinstance(value, float) and not math.isfinite(value) else value


def _plain(value):
    if isinstance(value, np.generic):
        return _finite(value.item())
    if isinstance(value, np.ndarray):
        return [_finite(v) for v in value.tolist()]
    raise TypeError(type(value).__name__)
