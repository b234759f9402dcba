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
position within ``gate`` sigma of a least-squares constant-velocity fit (in range /
cross-range terms for polar measurements), a fit chi-square within the ``fit_confidence``
quantile (2n - 4 degrees of freedom), at least ``min_hits`` of the window's scans. All
cells are handled as arrays (no loop over cells or hypotheses). Coordinates: x = column, y = row (pixels) for images,
metres for scans; time in frames or seconds.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from irdetect import tables
from irdetect.cluster import subtractive_cluster
from irdetect.hough import (fuzzy_hough_transform, hough_grid, hough_transform, nms_peaks,
                            rho_sigma)

log = logging.getLogger(__name__)

METHODS = ("hough-sc", "hough", "nms", "opencv", "parallel-hough", "fuzzy-parallel-hough",
           "mn-logic")

#: Defaults of every initiation parameter (``InitiateConfig`` mirrors them).
DEFAULTS = dict(
    method="hough-sc", n_theta=90, rho_step=2.0, tile=0.0, vote_fraction=0.6,
    parallel_fraction=0.8, q1=0.25, q2=0.65, sigma=1.5, sigma_range=0.0, sigma_azimuth=0.0,
    radius_rho=3.0, radius_theta=4.0, squash=1.25, accept_ratio=0.5, reject_ratio=0.15,
    merge_peaks=False, nms_size=5, verify=True, gate=3.0, v_min=0.0, v_max=0.0,
    min_hits=0.5, confirm_m=3, confirm_n=4, fit_confidence=0.99,
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
                        confirm_n: int = DEFAULTS["confirm_n"],
                        fit_confidence: float = DEFAULTS["fit_confidence"],
                        window: int = 10) -> np.ndarray:
    """Initiate tracks from the confirmed detections of an image sequence.

    Each detection is one measurement at time (frame_start + frame_end) / 2, in the "scan"
    given by its combined frame. Parameters are those of ``initiate_points`` (units: pixels,
    frames; ``sigma`` is the detection position error in px, ``v_min``/``v_max`` px/frame,
    0 = no bound).

    Parameters
    ----------
    detections : structured ndarray
        ``irdetect.tables.DETECTION`` rows (x = column, y = row).
    window : int
        Combined frames per initiation window (Zhang et al.'s M scans; 0 = the whole
        sequence in one window). Windows overlap by half (``scan_windows`` with step
        ``window // 2``); a sequence of at most ``window`` combined frames is one window.
        Tracks of consecutive windows that fit one constant velocity together are one
        target and are merged (``merge_windows``).

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
    if int(window) != window or window < 0 or window == 1:
        raise ValueError(f"window must be 0 or an integer >= 2, got {window!r}")
    t = 0.5 * (det["frame_start"] + det["frame_end"]).astype(float)
    scan = det["combined_frame"]
    spans = (scan_windows(scan, window=int(window), step=max(1, int(window) // 2))
             if window else [])
    if len(spans) <= 1:
        rows, members = initiate_points(det["x"], det["y"], t, scan, **params)
    else:
        found = []
        for a, b in spans:
            sel = np.flatnonzero((scan >= a) & (scan <= b))
            r, m = initiate_points(det["x"][sel], det["y"][sel], t[sel], scan[sel], **params)
            found += [(row, sel[mm]) for row, mm in zip(r, m)]
        rows, members = merge_windows(found, det["x"], det["y"], t, scan,
                                      sigma=sigma, fit_confidence=fit_confidence)
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


def camera_at(camera, frames) -> np.ndarray:
    """The camera's offsets (n, 2) at (fractional) ``frames`` (n,): ``camera`` is a
    ``tables.CAMERA`` table or an array (T, 2) of the offsets of frames 0..T-1; linear
    between frames, the nearest end outside them."""
    c = np.asarray(camera)
    if c.dtype.names is not None:
        f, cx, cy = c["frame"].astype(float), c["dx"], c["dy"]
    else:
        c = c.reshape(-1, 2)
        f, cx, cy = np.arange(len(c), dtype=float), c[:, 0], c[:, 1]
    t = np.asarray(frames, float)
    if len(f) == 0:
        return np.zeros((len(t), 2))
    return np.column_stack([np.interp(t, f, cx), np.interp(t, f, cy)])


def track_positions(tracks, frames, camera=None) -> np.ndarray:
    """Image positions (x, y) px of tracks in frames.

    Parameters
    ----------
    tracks : structured ndarray
        ``tables.TRACK`` rows (n).
    frames : array_like of shape (m,)
        Frame indices.
    camera : CAMERA table or ndarray of shape (T, 2), optional
        The camera's offsets (``/camera`` of the results file); needed for ``scene``
        tracks, whose positions follow the camera: (x0, y0) + (vx, vy) (f - frame_start)
        + C_f - C_frame_start.

    Returns
    -------
    ndarray of shape (n, m, 2)
        Positions where the tracks' lines put them (also outside their frame spans).
    """
    tr = np.asarray(tracks)
    f = np.asarray(frames, float)
    dt = f[None, :] - tr["frame_start"][:, None]
    pos = np.stack([tr["x0"][:, None] + tr["vx"][:, None] * dt,
                    tr["y0"][:, None] + tr["vy"][:, None] * dt], axis=-1)
    scene = tr["scene"] if "scene" in (tr.dtype.names or ()) else np.zeros(len(tr), bool)
    if scene.any():
        if camera is None:
            raise ValueError("scene tracks need the camera's offsets (/camera)")
        cf = camera_at(camera, f)                                     # (m, 2)
        cs = camera_at(camera, tr["frame_start"][scene])              # (k, 2)
        pos[scene] += cf[None, :, :] - cs[:, None, :]
    return pos


def merge_windows(found, x, y, t, scan, *, sigma: float, fit_confidence: float):
    """One track per target from the tracks of overlapping initiation windows.

    Parameters
    ----------
    found : list of (row, members)
        Tracks of every window in window order: an ``initiate_points`` row and the
        indices of its measurements into ``x``, ``y``, ``t``, ``scan`` (arrays of shape
        (N,); x = column, y = row in px, t in frames).
    sigma, fit_confidence : float
        Measurement position error (px) and the chi-square confidence of the
        constant-velocity fit (``initiate_points``).

    Returns
    -------
    rows, members
        As ``initiate_points``, ordered by start time. Each track joins the first earlier
        track whose combined frames it overlaps or follows directly when the
        measurements of both fit one constant velocity (chi-square of the least-squares
        fit, 2n - 4 degrees of freedom, within ``fit_confidence``): two targets that cross
        fail the fit; a target whose track one window missed is still one track. Where
        both hold a measurement of a combined frame, the earlier track's is kept. A
        merged track is the fit of the union with the group's best score; a track merged
        with none is returned as it was.

    Notes
    -----
    Each track is tested against every earlier group at once: a group keeps the sums a
    least-squares fit needs (``_fit_chi2``), and the union's are the two sums less those
    of the measurements both hold (overlapping windows share detections): no pairwise
    fits, whose count grows with the square of the tracks (a loose configuration's
    thousands of detections: docs/results/verification.md, section 2).
    """
    from scipy.special import chdtri

    x, y, t = (np.asarray(a, np.float64) for a in (x, y, t))
    # per measurement: the sums a least-squares fit needs (n, t, t^2, x, x t, x^2, y, ...),
    # about the means (a fit's residual does not depend on the origin; smaller sums)
    u, v, w = (a - a.mean() if a.size else a for a in (x, y, t))
    point = np.column_stack([np.ones_like(w), w, w * w, u, u * w, u * u, v, v * w, v * v])
    groups: list[list] = []                 # [first row, members, best score, merged]
    sums = np.zeros((len(found), 9))       # per group: sums over its members
    last = np.zeros(len(found), np.int64)  # per group: its last scan
    owners: dict[int, list] = {}           # measurement -> groups holding it
    for row, m in found:                        # a loop over tracks
        k = len(groups)
        mu = np.unique(m)
        # every earlier group at once: the fit of its members with m's, from the sums
        # (members both hold are counted once), chi-square against the limit of its size
        shared = np.zeros((k, 9))
        for j in mu:                            # a loop over m's measurements
            for g in owners.get(int(j), ()):
                shared[g] += point[j]
        both = sums[:k] + point[mu].sum(axis=0) - shared
        ok = last[:k] >= scan[m].min() - 1     # overlapping or adjacent scans
        if fit_confidence < 1:
            ok &= (_fit_chi2(both) / sigma ** 2
                   <= chdtri(np.maximum(2 * both[:, 0] - 4, 1), 1 - fit_confidence))
        hit = np.flatnonzero(ok)
        if len(hit):
            g = int(hit[0])                     # the first earlier track that fits
            # where both tracks hold a measurement of a combined frame, the earlier
            # track's stays (two detections of one frame on the line: a crossing)
            new = np.setdiff1d(m[~np.isin(scan[m], scan[groups[g][1]])], groups[g][1])
            groups[g][1] = np.union1d(groups[g][1], new)
            groups[g][2] = max(groups[g][2], float(row["score"]))
            groups[g][3] = True
        else:
            g, new = k, mu
            groups.append([row, m, float(row["score"]), False])
        sums[g] += point[new].sum(axis=0)
        last[g] = scan[groups[g][1]].max()
        for j in new:
            owners.setdefault(int(j), []).append(g)
    rows = np.zeros(len(groups), _ROW)
    for i, (row, m, score, merged) in enumerate(groups):
        if not merged:
            rows[i] = row
            continue
        x0, y0, vx, vy, _ = fit_constant_velocity(x[m], y[m], t[m])
        t0, t1 = t[m].min(), t[m].max()
        theta = (math.atan2(vy, vx) + math.pi / 2) % math.pi if (vx or vy) else row["theta"]
        tm = 0.5 * (t0 + t1)
        rho = (x0 + vx * (tm - t0)) * math.cos(theta) + (y0 + vy * (tm - t0)) * math.sin(theta)
        rows[i] = (rho, theta, vx, vy, t0, t1, scan[m].min(), scan[m].max(), len(m), score,
                   x0, y0)
    order = np.argsort(rows["t_start"], kind="stable")
    return rows[order], [groups[i][1] for i in order]


def _fit_chi2(sums: np.ndarray) -> np.ndarray:
    """Residual sum of squares (x and y) of the least-squares constant-velocity fit of
    each row of ``sums`` (n, t, t^2, x, x t, x^2, y, y t, y^2 summed over its points),
    shape (G,); the residual of ``fit_constant_velocity`` squared times n."""
    n, st, stt = sums[:, 0], sums[:, 1], sums[:, 2]
    n = np.maximum(n, 1)
    var_t = stt - st * st / n
    # one time only (var_t 0 up to rounding): velocity 0, the spread about the mean
    timed = var_t > 1e-12 * np.maximum(stt, 1.0)
    var_t = np.where(timed, var_t, 1.0)
    out = np.zeros(len(sums))
    for sx, sxt, sxx in ((sums[:, 3], sums[:, 4], sums[:, 5]),
                         (sums[:, 6], sums[:, 7], sums[:, 8])):
        cov = np.where(timed, sxt - sx * st / n, 0.0)
        out += sxx - sx * sx / n - cov * cov / var_t
    return np.maximum(out, 0.0)


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
    for name in ("vote_fraction", "parallel_fraction", "q1", "q2", "min_hits",
                 "fit_confidence"):
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

    def error_axes(self, idx, p):
        """Error ellipse of measurements idx: (cos, sin) of the first axis, its sigma and
        the sigma across it. Polar: range and cross-range (r sigma_azimuth, floored at a
        tenth of sigma_range so a measurement at the radar stays finite); else a circle
        of ``sigma``."""
        if self.polar is not None and (p["sigma_range"] > 0 or p["sigma_azimuth"] > 0):
            r, b = self.polar[0][idx], self.polar[1][idx]
            floor = 0.1 * max(p["sigma_range"], p["sigma"])
            return (np.cos(b), np.sin(b), np.maximum(p["sigma_range"], floor),
                    np.maximum(r * p["sigma_azimuth"], floor))
        one = np.ones(np.shape(idx))
        return one, 0 * one, p["sigma"] * one, p["sigma"] * one

    def pair_sigma_rho(self, idx, theta, p):
        """rho sigma of measurement idx[i] at angle theta[i] (eq. 6 when polar)."""
        if self.polar is not None and (p["sigma_range"] > 0 or p["sigma_azimuth"] > 0):
            d = theta - self.polar[1][idx]
            return np.hypot(np.cos(d) * p["sigma_range"],
                            np.sin(d) * self.polar[0][idx] * p["sigma_azimuth"])
        return np.full(idx.size, float(p["sigma"]))


def _initiate(x, y, t, sidx, uscans, polar, p):
    win = _Window(x, y, t, sidx, uscans, polar, p)
    if p["method"] == "mn-logic":
        members = _mn_logic(win, p)
        n = len(members)
        return _finish(win, members, np.zeros(n, np.int64), np.zeros(n), np.zeros(n),
                       np.array([m.size for m in members], float), p)
    g, rho, theta, value = _select_peaks(win, p)
    ptr, mem = _support(win, g, rho, theta, p)
    if p["verify"]:
        src, members = _verify(win, ptr, mem, theta, p)
    else:
        src = np.flatnonzero(np.diff(ptr) >= 2)
        members = [mem[ptr[i]:ptr[i + 1]] for i in src]
    keep = _dedupe(members, g[src], value[src], win, within=p["verify"])
    src = src[keep]
    return _finish(win, [members[i] for i in keep], g[src], rho[src], theta[src], value[src], p)


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
    """Selected cells of every tile: arrays group, rho (tile-local), theta, value."""
    acc, thr = _accumulate(win, p)
    grid = win.grid
    method = p["method"]
    if method == "opencv":
        return _opencv_peaks(win, acc, thr, p)
    cand = np.argwhere(acc >= thr)               # (K, 3): group, rho index, theta index
    if method == "nms":
        cand = nms_peaks(acc, size=p["nms_size"], threshold=thr - 1e-9)
    elif method == "hough-sc" or (p["merge_peaks"] and method != "hough"):
        # all tiles in one call: the tiles' candidates never interact (groups)
        cl = subtractive_cluster(
            np.column_stack([grid.rho_centres[cand[:, 1]], grid.theta_centres[cand[:, 2]]]),
            radii=[p["radius_rho"] * grid.drho / (grid.rho_max - grid.rho_min),
                   p["radius_theta"] * grid.dtheta / math.pi],
            squash=p["squash"], accept_ratio=p["accept_ratio"],
            reject_ratio=p["reject_ratio"], bounds=[[grid.rho_min, 0.0], [grid.rho_max, math.pi]],
            wrap_lines=True, groups=cand[:, 0], labels=False)
        cand = cand[cl.index]
    return (cand[:, 0].astype(np.int64), grid.rho_centres[cand[:, 1]],
            grid.theta_centres[cand[:, 2]], acc[tuple(cand.T)])


def _opencv_peaks(win: _Window, acc, thr, p):
    import cv2

    grid = win.grid
    out = []
    for g in np.flatnonzero((acc >= thr).any(axis=(1, 2))):   # tiles holding candidates
        sl = win.group_members(g)
        pts = np.column_stack([win.lx[sl], win.ly[sl]]).astype(np.float32).reshape(-1, 1, 2)
        lines = cv2.HoughLinesPointSet(pts, 64, int(thr), grid.rho_min, grid.rho_max,
                                       grid.drho, grid.dtheta / 2, math.pi, grid.dtheta)
        if lines is not None:
            lines = lines.reshape(-1, 3).astype(float)
            out.append(np.column_stack([np.full(len(lines), g), lines[:, 1], lines[:, 2],
                                        lines[:, 0]]))
    if not out:
        return np.zeros(0, np.int64), np.zeros(0), np.zeros(0), np.zeros(0)
    a = np.concatenate(out)
    return a[:, 0].astype(np.int64), a[:, 1], a[:, 2], a[:, 3]


def _expand(starts, counts):
    """Concatenated ranges [starts[i], starts[i] + counts[i]) (CSR expansion)."""
    counts = np.asarray(counts, np.int64)
    offs = np.repeat(np.asarray(starts, np.int64) - np.cumsum(np.r_[0, counts[:-1]]), counts)
    return offs + np.arange(counts.sum())


def _support(win: _Window, g, rho, theta, p, chunk: int = 2_000_000):
    """Measurements supporting every selected cell, as CSR (ptr, original indices).

    Every (cell, measurement of the cell's tile) pair is tested at once: the measurement
    supports the cell when its distance to the cell's line is within the band (``gate``
    rho-sigma when verifying, the q1 membership level for the fuzzy paper form, half a
    cell otherwise). Pairs are built in chunks of about ``chunk``.
    """
    starts = win.group_slices
    cnt = starts[g + 1] - starts[g]
    if p["verify"]:
        k = p["gate"]
    elif p["method"] == "fuzzy-parallel-hough":
        k = math.sqrt(2 * math.log(1 / p["q1"])) if 0 < p["q1"] < 1 else 0.0
    else:
        k = 0.0
    counts = np.zeros(g.size, np.int64)
    mems = []
    bounds = np.searchsorted(np.cumsum(cnt), np.arange(chunk, cnt.sum() + chunk, chunk))
    lo = 0
    for hi in np.unique(np.r_[bounds + 1, g.size]):      # a few chunks of pairs
        hi = min(int(hi), g.size)
        if hi <= lo:
            continue
        pk = np.repeat(np.arange(lo, hi), cnt[lo:hi])
        pos = _expand(starts[g[lo:hi]], cnt[lo:hi])
        th = theta[pk]
        d = win.lx[pos] * np.cos(th) + win.ly[pos] * np.sin(th) - rho[pk]
        band = 0.5 * win.grid.drho
        if k > 0:
            band = np.maximum(band, k * win.pair_sigma_rho(win.pt[pos], th, p))
        ok = np.abs(d) <= band
        counts[lo:hi] = np.bincount(pk[ok] - lo, minlength=hi - lo)
        mems.append(win.pt[pos[ok]])
        lo = hi
    mem = np.concatenate(mems) if mems else np.zeros(0, np.int64)
    return np.r_[0, np.cumsum(counts)], mem


def _min_points(win, p):
    return max(2, int(math.ceil(p["min_hits"] * win.n_scans - 1e-9)))


def _verify(win: _Window, ptr, mem, theta, p, max_members: int = 64):
    """Constant-velocity check of the supporting measurements of every selected cell.

    Cells with the same measurement set are checked once; cells whose measurements cover
    fewer than ``min_hits`` of the scans are skipped. The rest are checked in batches of
    similar size (``_cv_batch``). A cell with more than ``max_members`` measurements
    keeps the ``max_members`` nearest its line (bounds the pair search).

    Returns
    -------
    src : ndarray of int
        Cell of every track.
    members : list of ndarray
        Original indices of every track's measurements.
    """
    need = _min_points(win, p)
    P = ptr.size - 1
    cnt = np.diff(ptr)
    pk = np.repeat(np.arange(P), cnt)
    # distinct scans per cell
    S = win.n_scans
    ps = np.unique(pk * S + win.sidx[mem])
    nscan = np.bincount(ps // S, minlength=P)
    # one check per distinct measurement set: a 64-bit hash of the set
    code = np.random.default_rng(12345).integers(1, 2**63, win.x.size, dtype=np.uint64)
    h = np.zeros(P, np.uint64)
    np.add.at(h, pk, code[mem])
    h ^= cnt.astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15)
    cand = np.flatnonzero(nscan >= need)
    _, first = np.unique(h[cand], return_index=True)
    cand = np.sort(cand[first])
    src, members = [], []
    K = np.minimum(cnt[cand], max_members)
    edges = [2, 6, 8, 10, 12, 14, 16, 20, 24, 28, 32, 40, 48, 56, max_members]
    for lo_k, hi_k in zip(edges[:-1], edges[1:]):           # size buckets: little padding
        sel = cand[(K > lo_k) & (K <= hi_k)] if lo_k > 2 else cand[K <= hi_k]
        if sel.size == 0:
            continue
        Q = hi_k * (hi_k - 1) // 2
        batch = max(1, 2_000_000 // (Q * hi_k))
        for a in range(0, sel.size, batch):
            cells = sel[a:a + batch]
            s, m = _cv_batch(win, ptr, mem, cells, theta[cells], hi_k, p)
            src += s
            members += m
    return np.array(src, np.int64), members


def _cv_batch(win: _Window, ptr, mem, cells, theta, K, p, max_tracks: int = 4):
    """Split the measurements of a batch of cells into constant-velocity tracks.

    Per cell: every pair of measurements of different scans is a hypothesis (position and
    speed along the cell's line, speed within [v_min, 1.2 v_max]); the hypothesis with
    the most scans within 2 ``gate`` sigma (then the smallest normalised residual) gives
    one measurement per scan, refined twice by a least-squares CV fit (nearest
    measurement per scan whose residual, normalised by its own error ellipse, is within
    1.15 ``gate``); the track is kept when it spans ``min_hits`` of the scans, its fitted
    speed is within bounds and the sum of its squared normalised residuals is within the
    ``fit_confidence`` quantile of chi-square with 2n - 4 degrees of freedom. Its
    measurements (and the hypothesis' inliers) leave the pool and the search repeats,
    up to ``max_tracks`` per cell. All cells of the batch are processed together as
    (cells, K) arrays padded to K measurements.
    """
    B = cells.size
    cnt = np.minimum(ptr[cells + 1] - ptr[cells], K)
    start = ptr[cells]
    # padded (B, K) member indices; for cells above K keep the K nearest the line
    full = ptr[cells + 1] - ptr[cells]
    idx = np.full((B, K), -1, np.int64)
    over = full > K
    rows = np.repeat(np.arange(B), cnt)
    cols = np.arange(cnt.sum()) - np.repeat(np.cumsum(np.r_[0, cnt[:-1]]), cnt)
    idx[rows, cols] = mem[_expand(start, cnt)]
    for b in np.flatnonzero(over):                    # rare: crowded cells
        m = mem[ptr[cells[b]]:ptr[cells[b] + 1]]
        across = win.x[m] * math.cos(theta[b]) + win.y[m] * math.sin(theta[b])
        idx[b] = m[np.argsort(np.abs(across - np.median(across)), kind="stable")[:K]]
    valid = idx >= 0
    ii = np.where(valid, idx, 0)
    x, y, t = win.x[ii], win.y[ii], win.t[ii]
    sc = win.sidx[ii]
    sig = win.sigma[ii]
    axes = win.error_axes(ii, p)                  # per-measurement error ellipse
    S = win.n_scans
    onehot = ((sc[:, :, None] == np.arange(S)[None, None, :]) & valid[:, :, None])
    onehot_f = onehot.astype(np.float32)
    along = -x * np.sin(theta)[:, None] + y * np.cos(theta)[:, None]
    ia, ib = np.triu_indices(K, 1)
    dt = t[:, ib] - t[:, ia]
    need = _min_points(win, p)
    gate = p["gate"]
    vmin, vmax = p["v_min"], p["v_max"]
    tol = 2 * gate * sig                                           # (B, K)
    pool = valid.copy()
    done = np.zeros(B, bool)
    ntr = np.zeros(B, np.int64)
    src, out = [], []
    br = np.arange(B)
    for _ in range(2 * max_tracks):                    # rounds over all cells at once
        done |= (pool.sum(axis=1) < need) | (ntr >= max_tracks)
        if done.all():
            break
        ok_pair = pool[:, ia] & pool[:, ib] & (dt != 0) & ~done[:, None]
        v = (along[:, ib] - along[:, ia]) / np.where(dt != 0, dt, 1.0)
        ok_pair &= np.abs(v) >= vmin
        if vmax > 0:
            ok_pair &= np.abs(v) <= vmax * 1.2
        s0 = along[:, ia] - v * t[:, ia]
        res = np.abs(along[:, None, :] - (s0[:, :, None] + v[:, :, None] * t[:, None, :]))
        inl = (res <= tol[:, None, :]) & pool[:, None, :] & ok_pair[:, :, None]
        nsc = (np.matmul(inl.astype(np.float32), onehot_f) > 0).sum(axis=2)   # (B, Q)
        cost = np.where(inl, res / tol[:, None, :], 1.0).sum(axis=2)
        score = np.where(ok_pair, nsc - cost / (K + 1), -np.inf)
        best = np.argmax(score, axis=1)
        nbest = nsc[br, best]
        done |= ~np.isfinite(score[br, best]) | (nbest < need)
        cand = inl[br, best] & ~done[:, None]                      # (B, K)
        members = _one_per_scan(np.where(cand, res[br, best], np.inf), onehot)
        for _r in range(2):                                        # LS refinement
            e = _fit_error(x, y, t, members, axes)
            members = _one_per_scan(np.where(pool & (e <= gate * 1.15), e, np.inf), onehot)
        n_m = members.sum(axis=1)
        vx, vy = _fit_velocity(x, y, t, members)
        speed = np.hypot(vx, vy)
        good = (n_m >= need) & ~done & (speed >= vmin) & ((vmax <= 0) | (speed <= vmax))
        if p["fit_confidence"] < 1:
            # chi-square of the fit in the measurements' own error terms, 2n - 4 dof
            chi2 = np.where(members, _fit_error(x, y, t, members, axes) ** 2, 0.0).sum(axis=1)
            # the chi-square quantile by scipy.special (scipy.stats costs ~1 s to import)
            from scipy.special import chdtri

            limit = chdtri(np.maximum(2 * n_m - 4, 1), 1 - p["fit_confidence"])
            good &= (n_m < 3) | (chi2 <= limit)
        for b in np.flatnonzero(good):                 # accepted tracks (a handful)
            src.append(int(cells[b]))
            out.append(idx[b][members[b]])
        ntr += good
        pool &= ~(members | cand)
    return src, out


def _one_per_scan(score, onehot):
    """(B, K) mask keeping, per cell and scan, the member of least finite score."""
    B, K, S = onehot.shape
    s3 = np.where(onehot, score[:, :, None], np.inf)              # (B, K, S)
    arg = np.argmin(s3, axis=1)                                   # (B, S)
    fin = np.isfinite(np.take_along_axis(s3, arg[:, None, :], axis=1)[:, 0, :])
    out = np.zeros((B, K), bool)
    b, s = np.nonzero(fin)
    out[b, arg[b, s]] = True
    return out


def _fit_moments(x, y, t, m):
    n = np.maximum(m.sum(axis=1), 1)
    tm = (t * m).sum(axis=1) / n
    xm = (x * m).sum(axis=1) / n
    ym = (y * m).sum(axis=1) / n
    dt = (t - tm[:, None]) * m
    var = (dt ** 2).sum(axis=1)
    vx = np.where(var > 0, (dt * (x - xm[:, None])).sum(axis=1) / np.where(var > 0, var, 1), 0.0)
    vy = np.where(var > 0, (dt * (y - ym[:, None])).sum(axis=1) / np.where(var > 0, var, 1), 0.0)
    return tm, xm, ym, vx, vy


def _fit_velocity(x, y, t, m):
    return _fit_moments(x, y, t, m)[3:]


def _fit_error(x, y, t, m, axes):
    """(B, K) normalised distance of every measurement to its cell's CV fit of the
    members m: sqrt(e_r^2 / s_r^2 + e_c^2 / s_c^2), e split along the error axes."""
    tm, xm, ym, vx, vy = _fit_moments(x, y, t, m)
    ex = x - (xm[:, None] + vx[:, None] * (t - tm[:, None]))
    ey = y - (ym[:, None] + vy[:, None] * (t - tm[:, None]))
    cx, sx, s_r, s_c = axes
    e = np.hypot((ex * cx + ey * sx) / s_r, (ey * cx - ex * sx) / s_c)
    return np.where(m.sum(axis=1)[:, None] >= 2, e, np.inf)


def _dedupe(members, groups, value, win, within: bool = False):
    """Indices of the tracks kept: drop a track sharing half its measurements or more
    with a better (longer, then higher-valued) track.

    Without ``within`` only tracks of other tiles count (the same track seen by
    overlapping tiles), so the peak clustering of a method in the paper's form
    (``verify=False``) stays visible; with ``within`` (``verify=True``) two selected cells
    that lead to the same constant-velocity track give it once.
    """
    n = len(members)
    if n < 2 or (win.n_groups == 1 and not within):
        return list(range(n))
    sizes = np.array([m.size for m in members])
    order = np.lexsort((-np.asarray(value, float), -sizes))
    owner = np.full(win.x.size, -1)
    kept = []
    for i in order:                          # greedy over tracks, cheap steps
        m, g = members[i], groups[i]
        own = owner[m]
        other = (own >= 0) & ((own != g) | within)
        if np.count_nonzero(other) * 2 >= m.size:
            continue
        owner[m[own < 0]] = g
        kept.append(i)
    return sorted(kept)


def _finish(win: _Window, members, g, rho, theta, value, p):
    """Result rows: a least-squares CV fit of every track's measurements (vectorised)."""
    n = len(members)
    rows = np.zeros(n, _ROW)
    if n == 0:
        return rows, []
    cnt = np.array([m.size for m in members])
    mem = np.concatenate(members)
    tid = np.repeat(np.arange(n), cnt)
    x, y, t = win.x[mem], win.y[mem], win.t[mem]
    w = np.bincount(tid, minlength=n).astype(float)
    tm = np.bincount(tid, t, n) / w
    xm = np.bincount(tid, x, n) / w
    ym = np.bincount(tid, y, n) / w
    dtt = t - tm[tid]
    var = np.bincount(tid, dtt ** 2, n)
    safe = np.where(var > 0, var, 1.0)
    vx = np.where(var > 0, np.bincount(tid, dtt * (x - xm[tid]), n) / safe, 0.0)
    vy = np.where(var > 0, np.bincount(tid, dtt * (y - ym[tid]), n) / safe, 0.0)
    t_start = np.minimum.reduceat(t, np.r_[0, np.cumsum(cnt)[:-1]])
    t_end = np.maximum.reduceat(t, np.r_[0, np.cumsum(cnt)[:-1]])
    x0 = xm + vx * (t_start - tm)
    y0 = ym + vy * (t_start - tm)
    s_lo = np.minimum.reduceat(win.sidx[mem], np.r_[0, np.cumsum(cnt)[:-1]])
    s_hi = np.maximum.reduceat(win.sidx[mem], np.r_[0, np.cumsum(cnt)[:-1]])
    if p["verify"] or p["method"] == "mn-logic":
        moving = np.hypot(vx, vy) > 0
        th = np.where(moving, (np.arctan2(vy, vx) + math.pi / 2) % math.pi, theta % math.pi)
        tmid = 0.5 * (t_start + t_end)
        rh = (xm + vx * (tmid - tm)) * np.cos(th) + (ym + vy * (tmid - tm)) * np.sin(th)
        ps = np.unique(tid * win.n_scans + win.sidx[mem])
        score = np.bincount(ps // win.n_scans, minlength=n) / win.n_scans
    else:
        th = theta
        rh = rho + win.cx[g] * np.cos(theta) + win.cy[g] * np.sin(theta)
        score = np.asarray(value, float)
    for name, col in (("rho", rh), ("theta", th), ("vx", vx), ("vy", vy), ("t_start", t_start),
                      ("t_end", t_end), ("scan_start", win.uscans[s_lo]),
                      ("scan_end", win.uscans[s_hi]), ("n_points", cnt), ("score", score),
                      ("x0", x0), ("y0", y0)):
        rows[name] = col
    return rows, [np.asarray(m) for m in members]


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
        kept.append(m)
    return kept
