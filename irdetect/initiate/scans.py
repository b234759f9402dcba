"""Track initiation on radar-style measurement scans (``/scans``) in sliding windows.

Coordinates in the file's units (x, y; range, azimuth in rad for polar scans), time in s.
The parameters come from the sensor model (``irdetect.initiate.sensor.derive_params``)
or are given.
"""

from __future__ import annotations

import logging

import numpy as np

from irdetect import tables
from irdetect.initiate.base import check_params
from irdetect.initiate.clutter import separability
from irdetect.initiate.common import scan_windows
from irdetect.initiate.contract import initiate_points

log = logging.getLogger(__name__)


def initiate_scans(scans, *, window: int = 10, step: int | None = None, **params) -> np.ndarray:
    """Initiate tracks on radar-style scans in a sliding window of ``window`` scans.

    Parameters
    ----------
    scans : structured ndarray
        ``irdetect.tables.SCAN`` rows (scan, time in s, x, y in m; range, azimuth
        optional / NaN). Rows may come in any order.
    window, step : int
        Window length in scans and the step between window starts (default: window, i.e.
        disjoint windows).
    **params
        As ``initiate_points``. With ``false_tracks`` > 0 a window whose clutter is past
        the separable limit (``irdetect.initiate.clutter.separability``) is named in one
        warning for the run.

    Returns
    -------
    structured ndarray
        ``irdetect.tables.SCAN_TRACK`` rows, velocities in m/s, ``window_start`` the first
        scan of the window the track was initiated in.
    """
    sc = np.asarray(scans)
    for name in ("scan", "time", "x", "y"):
        if sc.dtype.names is None or name not in sc.dtype.names:
            raise ValueError(f"scans lack the field {name!r}")
    p = check_params(params)
    parts, past = [], []
    has_polar = "range" in sc.dtype.names and "azimuth" in sc.dtype.names
    for a, b in scan_windows(sc["scan"], window=window, step=step):
        sel = np.flatnonzero((sc["scan"] >= a) & (sc["scan"] <= b))
        w = sc[sel]
        rows, members = initiate_points(
            w["x"], w["y"], w["time"], w["scan"], range_=w["range"] if has_polar else None,
            azimuth=w["azimuth"] if has_polar else None, **params)
        out = tables.from_columns(tables.SCAN_TRACK, n=len(rows))
        for name in ("rho", "theta", "vx", "vy", "scan_start", "scan_end", "n_points",
                     "score", "x0", "y0"):
            out[name] = rows[name]
        out["window_start"] = a
        parts.append(out)
        if p["verify"] and p["false_tracks"] > 0:
            load, limit = separability(
                w["x"], w["y"], w["time"], int(np.unique(w["scan"]).size), p,
                range_=w["range"] if has_polar and np.isfinite(w["range"]).all() else None,
                explained=int(sum(m.size for m in members)))
            if load > limit:
                past.append((load, limit))
    if past:
        load, limit = max(past)
        log.warning("clutter too dense for the sensor's error: %.3g clutter points per "
                    "%g-sigma gate per scan (%.0fx the separable limit %.3g at %g false "
                    "tracks per window) in %d of %d windows; no test can tell a target "
                    "from chains of clutter there, so their clutter tracks are dropped",
                    load, p["gate"], load / limit, limit, p["false_tracks"], len(past),
                    len(parts))
    out = np.concatenate(parts) if parts else tables.empty("scan_tracks")
    out["track_id"] = np.arange(len(out))
    return out
