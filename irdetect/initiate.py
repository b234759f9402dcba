"""Track initiation from point measurements gathered over several scans (or combined frames).

Methods (``method=``):

``hough-sc``
    Zhang, Su & Ma (2010): Hough accumulator, every cell with at least T votes is a
    candidate, subtractive clustering of the candidates' (rho, theta), one track per centre.
``hough``
    Plain threshold baseline: every cell with at least T votes is a track.
``nms``
    Greedy non-maximum suppression of the accumulator (cell units) instead of clustering.
``opencv``
    ``cv2.HoughLinesPointSet`` (OpenCV's own voting and local-maximum test).
``parallel-hough``
    Lu et al. (2013): one binary accumulator per scan; a cell counts only when every scan
    votes for it; cells at ``parallel_fraction`` x peak or more are tracks.
``fuzzy-parallel-hough``
    Liang, Wang & Guo (2015): Gaussian memberships (eq. 6-8) per scan, rule q1 on every
    scan, cells at ``q2`` x peak or more are tracks; ``merge_peaks=True`` merges the cells
    of a peak by subtractive clustering.
``mn-logic``
    Sequential M-of-N logic (MATLAB ``trackHistoryLogic``) with a velocity gate.

Every Hough method recovers the measurements supporting each selected cell; with
``verify=True`` (the default, beyond the papers) they are kept only when they form a
constant-velocity track: one measurement per scan, speed within [v_min, v_max], every
position within ``gate`` sigma of a least-squares constant-velocity fit, at least
``min_hits`` of the window's scans. Coordinates: x = column, y = row (pixels) for images,
metres for scans; time in frames or seconds.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from irdetect import tables
from irdetect.cluster import subtractive_cluster
from irdetect.hough import (HoughGrid, fuzzy_hough_transform, hough_grid, hough_transform,
                            nms_peaks, rho_sigma)

log = logging.getLogger(__name__)

METHODS = ("hough-sc", "hough", "nms", "opencv", "parallel-hough", "fuzzy-parallel-hough",
           "mn-logic")

#: Defaults of every initiation parameter (``InitiateConfig`` mirrors them).
DEFAULTS = dict(
    method="hough-sc", n_theta=90, rho_step=2.0, tile=0.0, vote_fraction=0.6,
    parallel_fraction=0.8, q1=0.25, q2=0.65, sigma=1.0, sigma_range=0.0, sigma_azimuth=0.0,
    radius_rho=3.0, radius_theta=4.0, squash=1.25, accept_ratio=0.5, reject_ratio=0.15,
    merge_peaks=False, nms_size=5, verify=True, gate=3.0, v_min=0.0, v_max=0.0,
    min_hits=0.5, confirm_m=3, confirm_n=4,
)

#: Internal result: one row per track, times in the input's unit.
_ROW = np.dtype([
    ("rho", "<f8"), ("theta", "<f8"), ("vx", "<f8"), ("vy", "<f8"), ("t_start", "<f8"),
    ("t_end", "<f8"), ("scan_start", "<i8"), ("scan_end", "<i8"), ("n_points", "<i8"),
    ("score", "<f8"), ("x0", "<f8"), ("y0", "<f8"),
])


# ------------------------------------------------------------------------------------------
# public functions

def fit_constant_velocity(x, y, t):
    """Least-squares constant-velocity fit x(t) = x0 + vx (t - t0), y likewise.

    Parameters
    ----------
    x, y, t : array_like of shape (N,)
        Positions (x = column, y = row; or metres) and times; t0 = min(t).

    Returns
    -------
    x0, y0, vx, vy, rms : float
        Position at t0, velocity (units per time unit) and the rms 2-D residual. With a
        single time (all points of one scan) the velocity is 0 and the position the mean.
    """
    x, y, t = (np.asarray(a, float).ravel() for a in (x, y, t))
    if x.size == 0:
        raise ValueError("fit_constant_velocity needs at least one point")
    t0 = t.min()
    dt = t - t.mean()
    var = (dt ** 2).sum()
    if var > 0:
        vx = (dt * (x - x.mean())).sum() / var
        vy = (dt * (y - y.mean())).sum() / var
    else:
        vx = vy = 0.0
    x0 = x.mean() + vx * (t0 - t.mean())
    y0 = y.mean() + vy * (t0 - t.mean())
    res = np.hypot(x - (x0 + vx * (t - t0)), y - (y0 + vy * (t - t0)))
    return float(x0), float(y0), float(vx), float(vy), float(np.sqrt((res ** 2).mean()))


def initiate_points(x, y, t, scan, *, range_=None, azimuth=None, **params):
    """Initiate tracks from measurements of one window of scans.

    Parameters
    ----------
    x, y : array_like of shape (N,)
        Measurement positions (x = column, y = row in pixels; or metres).
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
    p = _check_params(params)
    x, y, t = (np.asarray(a, float).ravel() for a in (x, y, t))
    scan = np.asarray(scan).ravel()
    if not (x.size == y.size == t.size == scan.size):
        raise ValueError(f"x, y, t, scan differ in length: {x.size}, {y.size}, {t.size}, "
                         f"{scan.size}")
    if not (np.isfinite(x).all() and np.isfinite(y).all() and np.isfinite(t).all()):
        raise ValueError("x, y or t hold NaN or inf")
    if scan.size and not np.issubdtype(scan.dtype, np.integer):
        raise ValueError(f"scan must be integers, got dtype {scan.dtype}")
    polar = None
    if range_ is not None and azimuth is not None:
        polar = (np.asarray(range_, float).ravel(), np.asarray(azimuth, float).ravel())
        if not (polar[0].size == x.size and polar[1].size == x.size):
            raise ValueError("range_ and azimuth need one value per measurement")
        if not (np.isfinite(polar[0]).all() and np.isfinite(polar[1]).all()):
            polar = None                         # Cartesian measurements: NaN polar columns
    uscans = np.unique(scan)
    if uscans.size < 2:
        return np.zeros(0, _ROW), []
    sidx = np.searchsorted(uscans, scan)
    return _initiate(x, y, t, sidx, uscans, polar, p)


def initiate_detections(detections, *, method: str = DEFAULTS["method"],
                        n_theta: int = DEFAULTS["n_theta"],
                        rho_step: float = DEFAULTS["rho_step"], tile: float = DEFAULTS["tile"],
                        vote_fraction: float = DEFAULTS["vote_fraction"],
                        parallel_fraction: float = DEFAULTS["parallel_fraction"],
                        q1: float = DEFAULTS["q1"], q2: float = DEFAULTS["q2"],
                        sigma: float = DEFAULTS["sigma"],
                        sigma_range: float = DEFAULTS["sigma_range"],
                        sigma_azimuth: float = DEFAULTS["sigma_azimuth"],
                        radius_rho: float = DEFAULTS["radius_rho"],
                        radius_theta: float = DEFAULTS["radius_theta"],
                        squash: float = DEFAULTS["squash"],
                        accept_ratio: float = DEFAULTS["accept_ratio"],
                        reject_ratio: float = DEFAULTS["reject_ratio"],
                        merge_peaks: bool = DEFAULTS["merge_peaks"],
                        nms_size: int = DEFAULTS["nms_size"], verify: bool = DEFAULTS["verify"],
                        gate: float = DEFAULTS["gate"], v_min: float = DEFAULTS["v_min"],
                        v_max: float = DEFAULTS["v_max"], min_hits: float = DEFAULTS["min_hits"],
                        confirm_m: int = DEFAULTS["confirm_m"],
                        confirm_n: int = DEFAULTS["confirm_n"]) -> np.ndarray:
    """Initiate tracks from the confirmed detections of an image sequence.

    Each detection is one measurement at time (frame_start + frame_end) / 2, in the "scan"
    given by its combined frame. Parameters are those of ``initiate_points`` (units: pixels,
    frames; ``sigma`` is the detection position error in px, ``v_min``/``v_max`` px/frame,
    0 = no bound).

    Parameters
    ----------
    detections : structured ndarray
        ``irdetect.tables.DETECTION`` rows (x = column, y = row).

    Returns
    -------
    structured ndarray
        ``irdetect.tables.TRACK`` rows: rho, theta (rho = x cos(theta) + y sin(theta),
        theta in [0, pi)), vx, vy in px/frame, frame_start / frame_end of the members'
        windows, n_points, score, x0, y0 at frame_start. Empty (with its fields) when
        there are fewer than two combined frames or nothing forms a track.

    Examples
    --------
    >>> import numpy as np
    >>> from irdetect import tables
    >>> k = np.arange(8)
    >>> det = tables.from_columns(tables.DETECTION, x=10 + 12.0 * k, y=20 + 6.0 * k,
    ...     frame_start=12 * k, frame_end=12 * k + 11, combined_frame=k)
    >>> tr = initiate_detections(det)
    >>> len(tr), round(float(tr["vx"][0]), 2), round(float(tr["vy"][0]), 2)
    (1, 1.0, 0.5)
    """
    params = {k: v for k, v in locals().items() if k in DEFAULTS}
    det = np.asarray(detections)
    for name in ("x", "y", "frame_start", "frame_end", "combined_frame"):
        if det.dtype.names is None or name not in det.dtype.names:
            raise ValueError(f"detections lack the field {name!r}")
    t = 0.5 * (det["frame_start"] + det["frame_end"]).astype(float)
    rows, members = initiate_points(det["x"], det["y"], t, det["combined_frame"], **params)
    out = tables.from_columns(tables.TRACK, n=len(rows))
    if not len(rows):
        return out
    out["track_id"] = np.arange(len(rows))
    for name in ("rho", "theta", "vx", "vy", "n_points", "score"):
        out[name] = rows[name]
    for i, m in enumerate(members):
        out["frame_start"][i] = det["frame_start"][m].min()
        out["frame_end"][i] = det["frame_end"][m].max()
    shift = out["frame_start"] - rows["t_start"]
    out["x0"] = rows["x0"] + rows["vx"] * shift
    out["y0"] = rows["y0"] + rows["vy"] * shift
    return out


def scan_windows(scan_numbers, *, window: int, step: int | None = None):
    """Sliding windows of ``window`` consecutive scan numbers, ``step`` apart.

    Returns
    -------
    list of (first, last) inclusive scan numbers; a sequence shorter than the window
    gives one window over all of it.
    """
    if int(window) != window or window < 2:
        raise ValueError(f"window must be an integer >= 2, got {window}")
    step = window if step is None else step
    if int(step) != step or step < 1:
        raise ValueError(f"step must be an integer >= 1, got {step}")
    s = np.unique(np.asarray(scan_numbers))
    if s.size == 0:
        return []
    first, last = int(s.min()), int(s.max())
    if last - first + 1 <= window:
        return [(first, last)]
    starts = list(range(first, last - window + 2, step))
    if starts[-1] + window - 1 < last:
        starts.append(last - window + 1)
    return [(a, a + window - 1) for a in starts]


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
        As ``initiate_points``.

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
    _check_params(params)
    parts = []
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
    out = np.concatenate(parts) if parts else tables.empty("scan_tracks")
    out["track_id"] = np.arange(len(out))
    return out


# ------------------------------------------------------------------------------------------
# parameter checks

def _check_params(params: dict) -> dict:
    unknown = sorted(set(params) - set(DEFAULTS))
    if unknown:
        raise ValueError(f"unknown initiation parameter {unknown[0]!r}")
    p = {**DEFAULTS, **params}
    if p["method"] not in METHODS:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got {p['method']!r}")
    positive = ("rho_step", "sigma", "radius_rho", "radius_theta", "squash", "gate")
    for name in positive:
        if not (isinstance(p[name], (int, float)) and math.isfinite(p[name]) and p[name] > 0):
            raise ValueError(f"{name} must be a positive number, got {p[name]!r}")
    for name in ("tile", "sigma_range", "sigma_azimuth", "v_min", "v_max"):
        if not (math.isfinite(p[name]) and p[name] >= 0):
            raise ValueError(f"{name} must be >= 0, got {p[name]!r}")
    for name in ("vote_fraction", "parallel_fraction", "q1", "q2", "min_hits"):
        if not 0 <= p[name] <= 1:
            raise ValueError(f"{name} must lie in [0, 1], got {p[name]!r}")
    if not (0 < p["reject_ratio"] <= p["accept_ratio"] <= 1):
        raise ValueError(f"need 0 < reject_ratio <= accept_ratio <= 1, got "
                         f"{p['reject_ratio']}, {p['accept_ratio']}")
    for name in ("n_theta", "nms_size", "confirm_m", "confirm_n"):
        if int(p[name]) != p[name] or p[name] < 1:
            raise ValueError(f"{name} must be a positive integer, got {p[name]!r}")
    if p["n_theta"] > 100_000:
        raise ValueError(f"n_theta={p['n_theta']} is absurd (limit 100000 theta cells)")
    if p["confirm_m"] > p["confirm_n"]:
        raise ValueError(f"confirm_m={p['confirm_m']} exceeds confirm_n={p['confirm_n']}")
    if p["v_max"] and p["v_min"] > p["v_max"]:
        raise ValueError(f"v_min={p['v_min']} exceeds v_max={p['v_max']}")
    return p


# ------------------------------------------------------------------------------------------
# kernel

class _Window:
    """Measurements of one window with per-point sigma and the tiling of the plane."""

    def __init__(self, x, y, t, sidx, uscans, polar, p):
        self.x, self.y, self.t, self.sidx, self.uscans = x, y, t, sidx, uscans
        self.n_scans = uscans.size
        self.polar = polar
        # Conservative per-point position sigma: the larger polar error axis.
        s = np.full(x.size, p["sigma"])
        if polar is not None:
            s = np.maximum(s, np.maximum(p["sigma_range"], polar[0] * p["sigma_azimuth"]))
        self.sigma = s
        tile = p["tile"]
        if tile > 0:
            # Overlapping square tiles of side `tile`, stride tile/2: any segment shorter
            # than tile/2 lies wholly inside at least one tile.
            stride = tile / 2
            x0, y0 = x.min(), y.min()
            nx = max(1, int(math.ceil((x.max() - x0) / stride)))
            ny = max(1, int(math.ceil((y.max() - y0) / stride)))
            ix = np.floor((x - x0) / stride).astype(np.int64)
            iy = np.floor((y - y0) / stride).astype(np.int64)
            pts, grp = [], []
            for ddx in (-1, 0):
                for ddy in (-1, 0):
                    tx, ty = ix + ddx, iy + ddy
                    ok = (tx >= 0) & (ty >= 0) & (tx < nx) & (ty < ny)
                    pts.append(np.flatnonzero(ok))
                    grp.append((ty * nx + tx)[ok])
            # points on the last row/column of cells also belong to the edge tiles above
            pts, grp = np.concatenate(pts), np.concatenate(grp)
            order = np.lexsort((pts, grp))
            self.pt, self.grp = pts[order], grp[order]
            self.n_groups = nx * ny
            gx, gy = np.arange(self.n_groups) % nx, np.arange(self.n_groups) // nx
            self.cx = x0 + (gx + 1) * stride
            self.cy = y0 + (gy + 1) * stride
            rmax = tile / math.sqrt(2) + p["rho_step"]
        else:
            self.pt = np.arange(x.size)
            self.grp = np.zeros(x.size, np.int64)
            self.n_groups = 1
            self.cx = np.zeros(1)
            self.cy = np.zeros(1)
            rmax = float(np.hypot(x, y).max()) + p["rho_step"]
        self.lx = x[self.pt] - self.cx[self.grp]
        self.ly = y[self.pt] - self.cy[self.grp]
        self.grid = hough_grid(rho_max=rmax, rho_step=p["rho_step"], n_theta=p["n_theta"],
                               n_groups=self.n_groups)
        starts = np.searchsorted(self.grp, np.arange(self.n_groups + 1))
        self.group_slices = starts

    def group_members(self, g):
        a, b = self.group_slices[g], self.group_slices[g + 1]
        return slice(a, b)

    def sigma_rho(self, sel, theta, p):
        """(len(sel), len(theta)) rho sigma of the pairs `sel` (eq. 6 when polar)."""
        idx = self.pt[sel]
        if self.polar is not None and (p["sigma_range"] > 0 or p["sigma_azimuth"] > 0):
            return rho_sigma(theta, x=self.x[idx], y=self.y[idx], sigma=0.0,
                             sigma_range=p["sigma_range"], sigma_azimuth=p["sigma_azimuth"],
                             range_=self.polar[0][idx], azimuth=self.polar[1][idx])
        return np.full((idx.size, np.size(theta)), p["sigma"])


def _initiate(x, y, t, sidx, uscans, polar, p):
    win = _Window(x, y, t, sidx, uscans, polar, p)
    if p["method"] == "mn-logic":
        tracks = _mn_logic(win, p)
        return _finish(win, tracks, p)
    peaks = _select_peaks(win, p)              # list of (group, rho_local, theta, value)
    tracks = []
    seen: dict = {}                            # member set -> tracks found from it
    for g, rho, theta, value in peaks:
        for members in _tracks_of_peak(win, g, rho, theta, p, seen):
            tracks.append((members, g, rho, theta, value))
    tracks = _dedupe(tracks, win, within=p["verify"])
    return _finish(win, tracks, p)


def _accumulate(win: _Window, p):
    """The accumulator of the method, shape (n_groups, n_rho, n_theta), and the threshold."""
    grid = win.grid
    method = p["method"]
    scan_of = win.sidx[win.pt]
    if method in ("hough", "hough-sc", "nms", "opencv"):
        acc = hough_transform(win.lx, win.ly, grid=grid, groups=win.grp, n_groups=win.n_groups)
        return acc, max(1.0, math.ceil(p["vote_fraction"] * win.n_scans - 1e-9))
    fuzzy = method == "fuzzy-parallel-hough"
    keep = np.ones((win.n_groups,) + grid.shape, bool)
    total = np.zeros((win.n_groups,) + grid.shape)
    q1 = p["q1"] if fuzzy else 0.0
    for s in range(win.n_scans):                 # one accumulator per scan (a handful)
        sel = np.flatnonzero(scan_of == s)
        if fuzzy:
            sr = win.sigma_rho(sel, grid.theta_centres, p)
            b = fuzzy_hough_transform(win.lx[sel], win.ly[sel], grid=grid, sigma_rho=sr,
                                      support=p["gate"], groups=win.grp[sel],
                                      n_groups=win.n_groups)
        else:
            b = hough_transform(win.lx[sel], win.ly[sel], grid=grid, groups=win.grp[sel],
                                n_groups=win.n_groups)
        keep &= b > q1
        total += b
    acc = np.where(keep, total, 0.0)
    peak = acc.max() if acc.size else 0.0
    frac = p["q2"] if fuzzy else p["parallel_fraction"]
    return acc, max(frac * peak, 1e-12)


def _select_peaks(win: _Window, p):
    acc, thr = _accumulate(win, p)
    grid = win.grid
    method = p["method"]
    out = []
    if method == "opencv":
        return _opencv_peaks(win, acc, thr, p)
    cand = np.argwhere(acc >= thr)               # (K, 3): group, rho index, theta index
    if cand.size == 0:
        return out
    vals = acc[tuple(cand.T)]
    rhos = grid.rho_centres[cand[:, 1]]
    thetas = grid.theta_centres[cand[:, 2]]
    cluster = method == "hough-sc" or (p["merge_peaks"] and method != "hough")
    groups = np.unique(cand[:, 0])
    for g in groups:                              # loop over tiles holding candidates
        k = np.flatnonzero(cand[:, 0] == g)
        if method == "nms":
            pk = nms_peaks(acc[g], size=p["nms_size"], threshold=thr - 1e-9)
            out += [(int(g), grid.rho_centres[j], grid.theta_centres[n], acc[g, j, n])
                    for j, n in pk]
        elif cluster:
            span_rho = grid.rho_max - grid.rho_min
            cl = subtractive_cluster(
                np.column_stack([rhos[k], thetas[k]]),
                radii=[p["radius_rho"] * grid.drho / span_rho,
                       p["radius_theta"] * grid.dtheta / math.pi],
                squash=p["squash"], accept_ratio=p["accept_ratio"],
                reject_ratio=p["reject_ratio"],
                bounds=[[grid.rho_min, 0.0], [grid.rho_max, math.pi]], wrap_lines=True)
            out += [(int(g), rhos[k][i], thetas[k][i], vals[k][i]) for i in cl.index]
        else:
            out += [(int(g), rhos[i], thetas[i], vals[i]) for i in k]
    return out


def _opencv_peaks(win: _Window, acc, thr, p):
    import cv2

    grid = win.grid
    out = []
    for g in np.flatnonzero((acc >= thr).any(axis=(1, 2))):
        sl = win.group_members(g)
        pts = np.column_stack([win.lx[sl], win.ly[sl]]).astype(np.float32).reshape(-1, 1, 2)
        lines = cv2.HoughLinesPointSet(pts, 64, int(thr), grid.rho_min, grid.rho_max,
                                       grid.drho, grid.dtheta / 2, math.pi, grid.dtheta)
        if lines is None:
            continue
        for votes, rho, theta in lines.reshape(-1, 3):
            out.append((int(g), float(rho), float(theta), float(votes)))
    return out


def _tracks_of_peak(win: _Window, g, rho, theta, p, seen=None):
    """Members of one selected cell, split into constant-velocity tracks when verifying."""
    sl = win.group_members(g)
    lx, ly = win.lx[sl], win.ly[sl]
    d = lx * math.cos(theta) + ly * math.sin(theta) - rho
    if p["verify"]:
        k = p["gate"]
    elif p["method"] == "fuzzy-parallel-hough":
        k = math.sqrt(2 * math.log(1 / p["q1"])) if 0 < p["q1"] < 1 else 0.0
    else:
        k = 0.0
    if k > 0:
        sr = win.sigma_rho(np.arange(sl.start, sl.stop), np.array([theta]), p)[:, 0]
        band = np.maximum(0.5 * win.grid.drho, k * sr)
    else:
        band = 0.5 * win.grid.drho
    idx = win.pt[sl][np.abs(d) <= band]
    if idx.size < 2:
        return []
    if not p["verify"]:
        return [idx]
    if np.unique(win.sidx[idx]).size < _min_points(win, p):
        return []
    key = idx.tobytes()
    if seen is not None and key in seen:       # the same measurements as an earlier cell
        return [] if p["verify"] else seen[key]
    found = _cv_tracks(win, idx, theta, p)
    if seen is not None:
        seen[key] = found
    return found


def _min_points(win, p):
    return max(2, int(math.ceil(p["min_hits"] * win.n_scans - 1e-9)))


def _cv_tracks(win: _Window, idx, theta, p, max_tracks: int = 4):
    """Split measurements near one line into constant-velocity tracks (exhaustive pairs)."""
    x, y, t, s_of, sig = win.x[idx], win.y[idx], win.t[idx], win.sidx[idx], win.sigma[idx]
    along = -x * math.sin(theta) + y * math.cos(theta)
    need = _min_points(win, p)
    pool = np.ones(idx.size, bool)
    out = []
    onehot = np.zeros((idx.size, win.n_scans), bool)
    onehot[np.arange(idx.size), s_of] = True
    while pool.sum() >= need and len(out) < max_tracks:
        live = np.flatnonzero(pool)
        i, j = np.triu_indices(live.size, 1)
        i, j = live[i], live[j]
        dt = t[j] - t[i]
        ok = dt != 0
        i, j, dt = i[ok], j[ok], dt[ok]
        v = (along[j] - along[i]) / dt
        speed_ok = np.abs(v) >= p["v_min"]
        if p["v_max"] > 0:
            speed_ok &= np.abs(v) <= p["v_max"] * 1.2
        i, j, v = i[speed_ok], j[speed_ok], v[speed_ok]
        if i.size == 0:
            break
        s0 = along[i] - v * t[i]
        res = np.abs(along[live][None, :] - (s0[:, None] + v[:, None] * t[live][None, :]))
        tol = 2 * p["gate"] * sig[live][None, :]
        inl = res <= tol
        nscan = (inl.astype(np.int32) @ onehot[live].astype(np.int32) > 0).sum(axis=1)
        cost = np.where(inl, res / tol, 1.0).sum(axis=1)
        best = np.lexsort((cost, -nscan))[0]
        if nscan[best] < need:
            break
        cand = live[inl[best]]
        r = res[best][inl[best]]
        members = _one_per_scan(cand, s_of[cand], r)
        members = _refine(win, idx, members, pool, p)
        pool[members] = False
        pool[cand] = False if members.size >= need else pool[cand]
        if members.size < need:
            pool[live[inl[best]]] = False     # this hypothesis is spent
            continue
        out.append(idx[members])
    return out


def _one_per_scan(cand, scans, r):
    order = np.lexsort((r, scans))
    cand, scans = cand[order], scans[order]
    first = np.r_[True, scans[1:] != scans[:-1]]
    return cand[first]


def _refine(win, idx, members, pool, p, rounds: int = 2):
    """LS fit, then re-take for each scan the pooled point nearest the fit within gate."""
    x, y, t, s_of, sig = win.x[idx], win.y[idx], win.t[idx], win.sidx[idx], win.sigma[idx]
    live = np.flatnonzero(pool)
    for _ in range(rounds):
        if members.size < 2:
            return members
        x0, y0, vx, vy, _ = fit_constant_velocity(x[members], y[members], t[members])
        t0 = t[members].min()
        e = np.hypot(x[live] - (x0 + vx * (t[live] - t0)), y[live] - (y0 + vy * (t[live] - t0)))
        ok = e <= p["gate"] * sig[live] * 1.15
        new = _one_per_scan(live[ok], s_of[live[ok]], e[ok])
        if np.array_equal(np.sort(new), np.sort(members)):
            break
        members = new
    if members.size >= 2:
        _, _, vx, vy, _ = fit_constant_velocity(x[members], y[members], t[members])
        speed = math.hypot(vx, vy)
        if speed < p["v_min"] or (p["v_max"] > 0 and speed > p["v_max"]):
            return members[:0]
    return members


def _dedupe(tracks, win, within: bool = False):
    """Drop a track sharing half its measurements or more with a better track.

    Without ``within`` only tracks of other tiles count (the same track seen by
    overlapping tiles), so the peak clustering of a method in the paper's form
    (``verify=False``) stays visible; with ``within`` (``verify=True``) two selected cells
    that lead to the same constant-velocity track give it once.
    """
    if len(tracks) < 2 or (win.n_groups == 1 and not within):
        return tracks
    order = sorted(range(len(tracks)), key=lambda i: (-len(tracks[i][0]), -tracks[i][4]))
    owner = np.full(win.x.size, -1)
    kept = []
    for i in order:
        m, g = tracks[i][0], tracks[i][1]
        own = owner[m]
        other = (own >= 0) & ((own != g) | within)
        if other.sum() * 2 >= m.size:
            continue
        owner[m[own < 0]] = g
        kept.append(tracks[i])
    return kept


def _finish(win: _Window, tracks, p):
    rows = np.zeros(len(tracks), _ROW)
    members = []
    for r, (m, g, rho, theta, value) in enumerate(tracks):
        m = np.asarray(m)
        x0, y0, vx, vy, rms = fit_constant_velocity(win.x[m], win.y[m], win.t[m])
        t_start, t_end = win.t[m].min(), win.t[m].max()
        if p["verify"] or p["method"] == "mn-logic":
            if math.hypot(vx, vy) > 0:
                th = (math.atan2(vy, vx) + math.pi / 2) % math.pi
            else:
                th = theta % math.pi
            tm = 0.5 * (t_start + t_end) - t_start
            rh = (x0 + vx * tm) * math.cos(th) + (y0 + vy * tm) * math.sin(th)
            score = np.unique(win.sidx[m]).size / win.n_scans
        else:
            th = theta
            rh = rho + win.cx[g] * math.cos(theta) + win.cy[g] * math.sin(theta)
            score = float(value)
        rows[r] = (rh, th, vx, vy, t_start, t_end, win.uscans[win.sidx[m].min()],
                   win.uscans[win.sidx[m].max()], m.size, score, x0, y0)
        members.append(m)
    return rows, members


# ------------------------------------------------------------------------------------------
# M/N logic

def _mn_logic(win: _Window, p):
    """M-of-N track confirmation (trackHistoryLogic) with a velocity gate, vectorised
    over tracks (one pass per scan).

    Every measurement not taken by a track of two hits or more starts a tentative track.
    A one-hit track pairs with every measurement of a later scan whose implied speed lies
    in [v_min, v_max] (give or take ``gate`` sigma), one new track per pair; a track of two
    or more hits predicts with the velocity of its first and last hits and takes the
    nearest measurement within ``gate`` sigma of the prediction (inflated for the velocity
    error). A track is confirmed when it holds ``confirm_m`` hits within its first
    ``confirm_n`` scans and dropped as soon as that has become impossible; a confirmed
    track keeps collecting hits until the window ends or ``confirm_n`` scans pass without
    one.
    """
    from scipy.spatial import cKDTree

    m_req, n_req = p["confirm_m"], p["confirm_n"]
    S = win.n_scans
    scan_t = np.zeros(S)
    scan_t[win.sidx] = win.t
    xy = np.column_stack([win.x, win.y])
    vmax = p["v_max"] if p["v_max"] > 0 else 1e300
    H = np.zeros((0, S), np.int64)
    start = np.zeros(0, np.int64)
    alive = np.zeros(0, bool)
    cols = np.arange(S)
    for s in range(S):
        pts = np.flatnonzero(win.sidx == s)
        used = np.zeros(pts.size, bool)
        hitmask = H[:, :s] >= 0
        nh = hitmask.sum(axis=1)
        if pts.size and H.shape[0]:
            tree = cKDTree(xy[pts])
            # tracks with two or more hits: predict and take the nearest in the gate
            k2 = np.flatnonzero(alive & (nh >= 2))
            if k2.size:
                first = np.argmax(hitmask[k2], axis=1)
                last = s - 1 - np.argmax(hitmask[k2][:, ::-1], axis=1)
                a, b = H[k2, first], H[k2, last]
                span = scan_t[last] - scan_t[first]
                dt = scan_t[s] - scan_t[last]
                v = (xy[b] - xy[a]) / span[:, None]
                pred = xy[b] + v * dt[:, None]
                radius = p["gate"] * win.sigma[b] * 1.15 * np.sqrt(1 + 2 * (dt / span) ** 2)
                dist, j = tree.query(pred, distance_upper_bound=float(radius.max()))
                ok = dist <= radius
                H[k2[ok], s] = pts[j[ok]]
                used[j[ok]] = True
            # one-hit tracks: branch on every measurement in the velocity gate
            k1 = np.flatnonzero(alive & (nh == 1))
            if k1.size:
                a = H[k1, np.argmax(hitmask[k1], axis=1)]
                dt = scan_t[s] - win.t[a]
                slack = p["gate"] * win.sigma[a] * 1.5
                near = tree.query_ball_point(xy[a], np.minimum(vmax * dt + slack, 1e300))
                counts = np.array([len(n) for n in near])
                if counts.sum():
                    src = np.repeat(np.arange(k1.size), counts)
                    j = np.concatenate([np.asarray(n, np.int64) for n in near if len(n)])
                    dist = np.hypot(*(xy[pts[j]] - xy[a[src]]).T)
                    ok = dist + slack[src] >= p["v_min"] * dt[src]
                    src, j = src[ok], j[ok]
                    branch = H[k1[src]].copy()
                    branch[:, s] = pts[j]
                    alive[k1[np.unique(src)]] = False   # carried on by its branches
                    H = np.vstack([H, branch])
                    start = np.r_[start, start[k1[src]]]
                    alive = np.r_[alive, np.ones(src.size, bool)]
        # new tentative tracks from the measurements nobody took
        fresh = pts[~used]
        Hn = np.full((fresh.size, S), -1, np.int64)
        Hn[:, s] = fresh
        H = np.vstack([H, Hn])
        start = np.r_[start, np.full(fresh.size, s)]
        alive = np.r_[alive, np.ones(fresh.size, bool)]
        # confirmation / deletion
        in_first = (cols[None, :] >= start[:, None]) & (cols[None, :] < start[:, None] + n_req)
        hits_first = ((H >= 0) & in_first & (cols[None, :] <= s)).sum(axis=1)
        remaining = np.maximum(0, start + n_req - 1 - s)
        conf = hits_first >= m_req
        alive &= conf | (hits_first + remaining >= m_req)
        last_hit = np.where(H[:, :s + 1] >= 0, cols[None, :s + 1], -1).max(axis=1)
        alive &= ~conf | (s - last_hit < n_req)
    in_first = (cols[None, :] >= start[:, None]) & (cols[None, :] < start[:, None] + n_req)
    conf = ((H >= 0) & in_first).sum(axis=1) >= m_req
    rows = [H[k][H[k] >= 0] for k in np.flatnonzero(conf)]
    rows.sort(key=lambda m: -m.size)
    # identical or heavily overlapping confirmed tracks: keep the longest
    owner = np.zeros(win.x.size, bool)
    kept = []
    for m in rows:
        if owner[m].sum() * 2 >= m.size:
            continue
        owner[m] = True
        kept.append((m, 0, 0.0, 0.0, float(m.size)))
    return kept
