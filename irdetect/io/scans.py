"""The ``/scans`` contract (shared/design/formats.md): read and write measurement scans.

A scans file holds ``/scans`` (fields scan, time in s, x, y in the file's units, e.g. m or
km; optional range, azimuth in radians) and optionally ``/truth`` (scan, target, x, y).
Root attributes describe the sensor: the sensor model ``sigma`` (Cartesian error per
axis), ``sigma_range``, ``sigma_azimuth`` (rad), ``speed_min``, ``speed_max`` (units per
s) that ``irdetect initiate`` derives its parameters from, and ``period``, ``max_range``,
``scenario``, ...
"""

from __future__ import annotations

import logging
import os

import h5py
import numpy as np

from irdetect import __version__, tables
from irdetect.errors import InputError, check_input_file
from irdetect.io.results import AtomicH5

log = logging.getLogger(__name__)


def write_scans(path: str | os.PathLike, scans: np.ndarray, *, truth: np.ndarray | None = None,
                attrs: dict | None = None, force: bool = False) -> None:
    """Write a scans file atomically (no partial file; existing output needs ``force``)."""
    with AtomicH5(path, force=force) as f:
        f.create_dataset("scans", data=np.asarray(scans, dtype=tables.SCAN))
        if truth is not None:
            f.create_dataset("truth", data=np.asarray(truth, dtype=tables.SCAN_TRUTH))
        f.attrs["irdetect_version"] = __version__
        for key, value in (attrs or {}).items():
            f.attrs[key] = value


def read_scans(path: str | os.PathLike):
    """Read and check a scans file.

    Rows are sorted by scan (input in any order is accepted). Measurements beyond the
    declared radar range (root attribute ``max_range`` and a ``range`` column) cannot come
    from the radar: they are dropped with a warning.

    Returns
    -------
    scans : structured ndarray
        ``tables.SCAN`` rows (range, azimuth NaN when absent).
    truth : structured ndarray or None
        ``tables.SCAN_TRUTH`` rows.
    attrs : dict
        Root attributes.

    Raises
    ------
    InputError
        Missing file or ``/scans``, missing fields, NaN or inf in scan/time/x/y, a scan
        whose time differs between rows, or times that go backwards as scans advance.
    """
    check_input_file(path, "scans file")
    try:
        with h5py.File(path, "r") as f:
            if "scans" not in f or f["scans"].dtype.names is None:
                raise InputError("no /scans table (fields scan, time, x, y)", path)
            raw = f["scans"][()]
            truth_raw = f["truth"][()] if "truth" in f and f["truth"].dtype.names else None
            attrs = {k: (v.decode() if isinstance(v, bytes) else
                         v.item() if isinstance(v, np.generic) else v) for k, v in f.attrs.items()}
    except FileNotFoundError:
        raise InputError("file not found", path) from None
    except OSError as exc:
        raise InputError(f"not a readable HDF5 file ({str(exc).splitlines()[0][:120]})",
                         path) from None
    missing = [n for n in ("scan", "time", "x", "y") if n not in raw.dtype.names]
    if missing:
        raise InputError(f"/scans lacks the field(s) {', '.join(missing)}", path)
    scans = tables.from_columns(tables.SCAN, **{n: raw[n] for n in tables.SCAN.names
                                                if n in raw.dtype.names})
    bad = ~(np.isfinite(scans["x"]) & np.isfinite(scans["y"]) & np.isfinite(scans["time"]))
    if bad.any():
        raise InputError(f"/scans has {int(bad.sum())} row(s) with NaN or inf time/x/y "
                         f"(first at row {int(np.flatnonzero(bad)[0])})", path)
    scans = scans[np.argsort(scans["scan"], kind="stable")]
    if scans.size:
        u, first = np.unique(scans["scan"], return_index=True)
        t_first = scans["time"][first]
        t_per_row = t_first[np.searchsorted(u, scans["scan"])]
        if not np.allclose(scans["time"], t_per_row, rtol=0, atol=1e-6 * max(1.0, np.abs(t_first).max())):
            raise InputError("rows of one scan carry different times", path)
        back = np.flatnonzero(np.diff(t_first) <= 0)
        if back.size:
            i = back[0]
            raise InputError(f"scan {u[i + 1]} is at time {t_first[i + 1]} s, not after scan "
                             f"{u[i]} at {t_first[i]} s: scan numbers and times disagree", path)
    max_range = attrs.get("max_range")
    if max_range and scans.size:
        r = np.where(np.isfinite(scans["range"]), scans["range"], np.hypot(scans["x"], scans["y"]))
        out = r > float(max_range)
        if out.any():
            log.warning("%s: dropped %d measurement(s) beyond the declared radar range %g m",
                        path, int(out.sum()), float(max_range))
            scans = scans[~out]
    truth = None
    if truth_raw is not None:
        missing = [n for n in tables.SCAN_TRUTH.names if n not in truth_raw.dtype.names]
        if missing:
            raise InputError(f"/truth lacks the field(s) {', '.join(missing)}", path)
        truth = tables.from_columns(tables.SCAN_TRUTH, **{n: truth_raw[n]
                                                          for n in tables.SCAN_TRUTH.names})
    return scans, truth, attrs


def describe_scans(path) -> list[str]:
    """Human lines describing a scans file (``irdetect info``)."""
    scans, truth, attrs = read_scans(path)
    n_scans = len(np.unique(scans["scan"]))
    polar = bool(scans.size) and bool(np.isfinite(scans["range"]).all())
    lines = [f"{path}: scans file ({'polar' if polar else 'Cartesian'} measurements)",
             f"  {len(scans)} measurements in {n_scans} scans"]
    if scans.size:
        lines.append(f"  time {scans['time'].min():g}..{scans['time'].max():g} s, x "
                     f"{scans['x'].min():.4g}..{scans['x'].max():.4g}, y "
                     f"{scans['y'].min():.4g}..{scans['y'].max():.4g}")
    sensor = [f"{k} {attrs[k]:g}" for k in ("sigma", "sigma_range", "sigma_azimuth",
                                             "speed_min", "speed_max")
              if isinstance(attrs.get(k), (int, float))]
    lines.append("  sensor model: " + (", ".join(sensor) if sensor else
                                       "none (irdetect initiate needs --sigma and --speed)"))
    if truth is not None:
        lines.append(f"  truth: {len(truth)} rows, {len(np.unique(truth['target']))} "
                     "target(s)")
    return lines
