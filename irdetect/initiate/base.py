"""Shared kernel of the initiators: parameters, the measurements of one window, support
recovery, de-duplication and the result rows (``irdetect.initiate``'s contract).

Coordinates: x = column, y = row (pixels) for images, the file's units for scans; time in
frames or seconds.
"""

from __future__ import annotations

import math

import numpy as np

from irdetect.hough import hough_grid, rho_sigma

METHODS = ("hough-sc", "hough", "nms", "opencv", "parallel-hough", "fuzzy-parallel-hough",
           "mn-logic")

#: Defaults of every initiation parameter (``InitiateConfig`` mirrors them).
DEFAULTS = dict(
    method="hough-sc", n_theta=90, rho_step=2.0, tile=0.0, vote_fraction=0.6, vote_band=0.0,
    parallel_fraction=0.8, q1=0.25, q2=0.65, sigma=1.5, sigma_range=0.0, sigma_azimuth=0.0,
    radius_rho=3.0, radius_theta=4.0, squash=1.25, accept_ratio=0.5, reject_ratio=0.15,
    merge_peaks=False, nms_size=5, verify=True, gate=3.0, v_min=0.0, v_max=0.0,
    min_hits=0.5, confirm_m=3, confirm_n=4, fit_confidence=0.99, false_tracks=0.0,
)

#: Internal result: one row per track, times in the input's unit.
ROW = np.dtype([
    ("rho", "<f8"), ("theta", "<f8"), ("vx", "<f8"), ("vy", "<f8"), ("t_start", "<f8"),
    ("t_end", "<f8"), ("scan_start", "<i8"), ("scan_end", "<i8"), ("n_points", "<i8"),
    ("score", "<f8"), ("x0", "<f8"), ("y0", "<f8"),
])


#: One measurement of a window (the input of every method's ``initiate``): position
#: (x = column, y = row in px, or the scans' units), time (frames or s), scan number and,
#: for polar scans, range and azimuth (rad; NaN otherwise).
POINT = np.dtype([("x", "<f8"), ("y", "<f8"), ("t", "<f8"), ("scan", "<i8"),
                  ("range", "<f8"), ("azimuth", "<f8")])


def check_params(params: dict) -> dict:
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
    for name in ("tile", "sigma_range", "sigma_azimuth", "v_min", "v_max", "false_tracks",
                 "vote_band"):
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



def sigma_axes(p, r=None):
    """Error-ellipse sigmas (along, across) of measurements at ranges ``r`` (any shape):
    range and cross-range (r sigma_azimuth, floored at a tenth of sigma_range so a
    measurement at the radar stays finite) for polar parameters and ranges, else
    ``sigma`` for both (``r`` None or no polar sigmas). Broadcastable to ``r``'s shape."""
    if r is not None and (p["sigma_range"] > 0 or p["sigma_azimuth"] > 0):
        floor = 0.1 * max(p["sigma_range"], p["sigma"])
        return (np.maximum(p["sigma_range"], floor),
                np.maximum(np.asarray(r, float) * p["sigma_azimuth"], floor))
    return float(p["sigma"]), float(p["sigma"])


class Window:
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
        the sigma across it (``sigma_axes``: range and cross-range for polar
        measurements, else a circle of ``sigma``)."""
        if self.polar is not None and (p["sigma_range"] > 0 or p["sigma_azimuth"] > 0):
            r, b = self.polar[0][idx], self.polar[1][idx]
            return (np.cos(b), np.sin(b), *sigma_axes(p, r))
        one = np.ones(np.shape(idx))
        return one, 0 * one, p["sigma"] * one, p["sigma"] * one

    def pair_sigma_rho(self, idx, theta, p):
        """rho sigma of measurement idx[i] at angle theta[i] (eq. 6 when polar)."""
        if self.polar is not None and (p["sigma_range"] > 0 or p["sigma_azimuth"] > 0):
            d = theta - self.polar[1][idx]
            return np.hypot(np.cos(d) * p["sigma_range"],
                            np.sin(d) * self.polar[0][idx] * p["sigma_azimuth"])
        return np.full(idx.size, float(p["sigma"]))


    @classmethod
    def from_points(cls, points, p):
        """The window of ``points`` (``POINT`` rows of at least two scans)."""
        x, y, t, scan, r, b = (np.ascontiguousarray(points[n]) for n in POINT.names)
        uscans = np.unique(scan)
        sidx = np.searchsorted(uscans, scan)
        polar = None
        if points.size and np.isfinite(r).all() and np.isfinite(b).all():
            polar = (r, b)
        return cls(x, y, t, sidx, uscans, polar, p)


def expand(starts, counts):
    """Concatenated ranges [starts[i], starts[i] + counts[i]) (CSR expansion)."""
    counts = np.asarray(counts, np.int64)
    offs = np.repeat(np.asarray(starts, np.int64) - np.cumsum(np.r_[0, counts[:-1]]), counts)
    return offs + np.arange(counts.sum())


def support(win: Window, g, rho, theta, p, chunk: int = 2_000_000):
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
        pos = expand(starts[g[lo:hi]], cnt[lo:hi])
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


def vote_threshold(vote_fraction: float, n_scans: int) -> int:
    """The votes a Hough cell needs: T = ceil(``vote_fraction`` x scans), at least 1
    (Zhang et al.'s threshold)."""
    return max(1, int(math.ceil(vote_fraction * n_scans - 1e-9)))


def min_points(win, p):
    return max(2, int(math.ceil(p["min_hits"] * win.n_scans - 1e-9)))



def dedupe(members, groups, value, win, within: bool = False):
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


def finish(win: Window, members, g, rho, theta, value, p):
    """Result rows: a least-squares CV fit of every track's measurements (vectorised)."""
    n = len(members)
    rows = np.zeros(n, ROW)
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

