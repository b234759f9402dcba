"""The one contract every initiator keeps, and the dispatch to the method modules.

``initiate(points, *, params) -> (rows, members)``: ``points`` are the measurements of one
window (``POINT`` rows: x, y, t, scan, range, azimuth), ``params`` every key of
``DEFAULTS`` (checked); ``rows`` one ``ROW`` per track (rho, theta in [0, pi), vx, vy,
t_start, t_end, scan_start, scan_end, n_points, score, x0, y0 at t_start), ``members``
the indices into ``points`` of every track's measurements. ``initiate_detections`` and
``initiate_scans`` turn the rows into ``tables.TRACK`` / ``tables.SCAN_TRACK`` rows.

A method module (``hough_sc``, ``parallel``, ``mn_logic``) exports ``METHODS`` and
``initiate``; ``METHOD_MODULES`` maps every method name to its module.
"""

from __future__ import annotations

import numpy as np

from irdetect.initiate import hough_sc, mn_logic, parallel
from irdetect.initiate.base import METHODS, POINT, ROW, check_params

#: method name -> module whose ``initiate(points, *, params)`` runs it
METHOD_MODULES = {m: mod for mod in (hough_sc, parallel, mn_logic) for m in mod.METHODS}
assert set(METHOD_MODULES) == set(METHODS)


def initiate(points, *, params):
    """Tracks of one window of measurements by ``params["method"]``.

    Parameters
    ----------
    points : structured ndarray
        ``POINT`` rows (x = column, y = row in px, or the scans' units; t in frames or s;
        scan an integer; range, azimuth (rad) of a radar at the origin, or NaN).
    params : dict
        Any of ``DEFAULTS`` (missing keys take the default).

    Returns
    -------
    rows : structured ndarray
        ``ROW``, one per track; empty (with its fields) for fewer than two scans.
    members : list of ndarray of int
        Indices into ``points`` of every track's measurements.
    """
    p = check_params(params)
    points = np.asarray(points)
    if np.unique(points["scan"]).size < 2:
        return np.zeros(0, ROW), []
    return METHOD_MODULES[p["method"]].initiate(points, params=p)


def initiate_points(x, y, t, scan, *, range_=None, azimuth=None, **params):
    """Initiate tracks from measurements of one window of scans.

    Parameters
    ----------
    x, y : array_like of shape (N,)
        Measurement positions (x = column, y = row in pixels; or the scans' units).
    t : array_like of shape (N,)
        Measurement times (frames or seconds); constant within a scan.
    scan : array_like of int, shape (N,)
        Scan (or combined-frame) number of each measurement.
    range_, azimuth : array_like of shape (N,), optional
        Polar measurements of a radar at the origin (for the fuzzy spread, eq. 6).
    **params
        Any of ``DEFAULTS`` (see ``InitiateConfig`` and docs/initiation.md).

    Returns
    -------
    rows : structured ndarray
        One row per track (rho, theta in [0, pi), vx, vy, t_start, t_end, scan_start,
        scan_end, n_points, score, x0, y0 at t_start).
    members : list of ndarray of int
        Indices (into the inputs) of every track's measurements.

    Raises
    ------
    ValueError
        Unknown method or parameter, a bad parameter value, NaN coordinates.
    """
    p = check_params(params)
    x, y, t = (np.asarray(a, float).ravel() for a in (x, y, t))
    scan = np.asarray(scan).ravel()
    if not (x.size == y.size == t.size == scan.size):
        raise ValueError(f"x, y, t, scan differ in length: {x.size}, {y.size}, {t.size}, "
                         f"{scan.size}")
    if not (np.isfinite(x).all() and np.isfinite(y).all() and np.isfinite(t).all()):
        raise ValueError("x, y or t hold NaN or inf")
    if scan.size and not np.issubdtype(scan.dtype, np.integer):
        raise ValueError(f"scan must be integers, got dtype {scan.dtype}")
    points = np.zeros(x.size, POINT)
    points["x"], points["y"], points["t"], points["scan"] = x, y, t, scan
    points["range"] = points["azimuth"] = np.nan
    if range_ is not None and azimuth is not None:
        r, b = np.asarray(range_, float).ravel(), np.asarray(azimuth, float).ravel()
        if not (r.size == x.size and b.size == x.size):
            raise ValueError("range_ and azimuth need one value per measurement")
        if np.isfinite(r).all() and np.isfinite(b).all():
            points["range"], points["azimuth"] = r, b   # else Cartesian: NaN polar columns
    return initiate(points, params=p)
