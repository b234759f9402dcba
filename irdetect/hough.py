"""Hough accumulators over point sets: standard, parallel (one per scan) and fuzzy.

A point (x, y) votes along its curve rho = x cos(theta) + y sin(theta) with theta in
[0, pi). Cells follow Zhang, Su & Ma (2010) eq. 2: theta cell n is centred at
theta_n = (n + 1/2) dtheta, dtheta = pi / n_theta (n counted from 0 here, from 1 in the
paper); rho cells likewise, centred at rho_min + (j + 1/2) drho. Coordinates are those of
the points: x = column, y = row in pixels for images, metres for scans.

Every accumulator can be split into independent groups (``groups``), e.g. overlapping
spatial tiles, so that one vectorised ``np.bincount`` fills all of them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Largest accumulator (cells over all groups) we agree to build: 4e7 cells is 320 MB of
#: float64. Larger requests are refused with the reason instead of exhausting memory.
MAX_CELLS = 40_000_000


@dataclass(frozen=True)
class HoughGrid:
    """A (rho, theta) cell grid.

    Attributes
    ----------
    rho_min, rho_max : float
        Edges of the rho range (units of the points).
    n_rho, n_theta : int
        Cell counts.
    """

    rho_min: float
    rho_max: float
    n_rho: int
    n_theta: int

    @property
    def drho(self) -> float:
        return (self.rho_max - self.rho_min) / self.n_rho

    @property
    def dtheta(self) -> float:
        return math.pi / self.n_theta

    @property
    def rho_centres(self) -> np.ndarray:
        """ndarray of shape (n_rho,): rho_min + (j + 1/2) drho."""
        return self.rho_min + (np.arange(self.n_rho) + 0.5) * self.drho

    @property
    def theta_centres(self) -> np.ndarray:
        """ndarray of shape (n_theta,): (n + 1/2) pi / n_theta (paper eq. 2)."""
        return (np.arange(self.n_theta) + 0.5) * self.dtheta

    @property
    def shape(self) -> tuple[int, int]:
        return (self.n_rho, self.n_theta)


def hough_grid(*, rho_max: float, rho_min: float | None = None, n_rho: int | None = None,
               rho_step: float | None = None, n_theta: int = 180,
               n_groups: int = 1, max_cells: int = MAX_CELLS) -> HoughGrid:
    """Build a cell grid from either a cell count or a cell size along rho.

    Parameters
    ----------
    rho_max : float
        Upper rho edge; ``rho_min`` defaults to ``-rho_max`` (lines through every
        quadrant). Liang et al. use rho range = twice the radar range.
    n_rho, rho_step : int or float
        Give one: the number of rho cells or their size.
    n_theta : int
        Number of theta cells over [0, pi).
    n_groups : int
        Number of accumulators of this grid that will be built together (tiles); counts
        towards ``max_cells``.
    max_cells : int
        Refuse grids with more cells than this (``n_rho * n_theta * n_groups``).

    Raises
    ------
    ValueError
        A non-positive or non-finite size, neither or both of n_rho / rho_step, or a grid
        larger than ``max_cells`` (the message gives the size and the reason).
    """
    rho_min = -rho_max if rho_min is None else rho_min
    if not (np.isfinite(rho_max) and np.isfinite(rho_min)) or rho_max <= rho_min:
        raise ValueError(f"rho range must be finite with rho_max > rho_min, got "
                         f"[{rho_min}, {rho_max}]")
    if (n_rho is None) == (rho_step is None):
        raise ValueError("give exactly one of n_rho and rho_step")
    if rho_step is not None:
        if not (np.isfinite(rho_step) and rho_step > 0):
            raise ValueError(f"rho_step must be a positive number, got {rho_step}")
        n_cells = (rho_max - rho_min) / rho_step
        if n_cells > max_cells:
            raise ValueError(f"rho_step={rho_step} gives {n_cells:.3g} rho cells, more than "
                             f"the {max_cells} cell limit")
        n_rho = max(1, int(math.ceil(n_cells - 1e-9)))
        rho_max = rho_min + n_rho * rho_step
    if int(n_rho) != n_rho or n_rho < 1:
        raise ValueError(f"n_rho must be a positive integer, got {n_rho}")
    if int(n_theta) != n_theta or n_theta < 1:
        raise ValueError(f"n_theta must be a positive integer, got {n_theta}")
    total = int(n_rho) * int(n_theta) * int(n_groups)
    if total > max_cells:
        raise ValueError(f"accumulator of {n_groups} x {n_rho} rho x {n_theta} theta = {total} "
                         f"cells exceeds the limit of {max_cells} (about "
                         f"{max_cells * 8 // 2**20} MB); use coarser cells")
    return HoughGrid(float(rho_min), float(rho_max), int(n_rho), int(n_theta))


def _check_points(x, y):
    x = np.asarray(x, dtype=float).ravel()
    y = np.asarray(y, dtype=float).ravel()
    if x.shape != y.shape:
        raise ValueError(f"x and y differ in length: {x.size} and {y.size}")
    if not (np.isfinite(x).all() and np.isfinite(y).all()):
        raise ValueError("x, y hold NaN or inf coordinates")
    return x, y


def curve_rho(x, y, grid: HoughGrid) -> np.ndarray:
    """rho of every point's curve at every theta cell centre.

    Returns
    -------
    ndarray of shape (N, n_theta)
        rho_i(theta_n) = x_i cos(theta_n) + y_i sin(theta_n) (paper eq. 1).
    """
    th = grid.theta_centres
    return np.outer(x, np.cos(th)) + np.outer(y, np.sin(th))


def hough_transform(x, y, *, grid: HoughGrid, weights=None, groups=None,
                    n_groups: int = 1, band=0.0) -> np.ndarray:
    """Standard (binary-vote) Hough accumulator: each point adds 1 (or its weight) to the
    cell its curve crosses in every theta column, and with a ``band`` to every cell of
    that column within ``band`` of its rho (once each: a cell's total still counts points).

    Parameters
    ----------
    x, y : array_like of shape (N,)
        Point coordinates (x = column, y = row; or metres).
    grid : HoughGrid
        Cell grid; curves leaving the rho range are not counted.
    weights : array_like of shape (N,), optional
        Vote per point (default 1).
    groups : array_like of int, shape (N,), optional
        Accumulator index of every point (0 .. n_groups-1), e.g. its spatial tile.
    band : float or array_like of shape (N,)
        Half-width in rho (the points' units) of each point's vote (0: the cell its curve
        crosses; the rho error of the point, so that points within their errors of one
        line share a cell wherever the cell edges fall).

    Returns
    -------
    ndarray of shape (n_groups, n_rho, n_theta)
        Vote totals, float64.
    """
    x, y = _check_points(x, y)
    w = np.ones(x.size) if weights is None else np.asarray(weights, dtype=float).ravel()
    g = np.zeros(x.size, np.int64) if groups is None else np.asarray(groups, np.int64).ravel()
    if w.shape != x.shape or g.shape != x.shape:
        raise ValueError("weights and groups must have one entry per point")
    if g.size and (g.min() < 0 or g.max() >= n_groups):
        raise ValueError(f"groups must lie in [0, {n_groups}), got [{g.min()}, {g.max()}]")
    b = np.broadcast_to(np.asarray(band, dtype=float), x.shape)
    if not (np.isfinite(b).all() and (b >= 0).all()):
        raise ValueError("band must be finite and >= 0")
    return _hough_kernel(x, y, w, g, grid, n_groups, b)


def _hough_kernel(x, y, w, g, grid, n_groups, band):
    size = n_groups * grid.n_rho * grid.n_theta
    acc = np.zeros(size)
    if x.size == 0:
        return acc.reshape((n_groups,) + grid.shape)
    r = (curve_rho(x, y, grid) - grid.rho_min) / grid.drho                 # (N, n_theta)
    half = (band / grid.drho)[:, None]
    lo = np.floor(r - half).astype(np.int64)
    hi = np.floor(r + half).astype(np.int64)
    n = np.arange(grid.n_theta)[None]
    wt = np.broadcast_to(w[:, None], r.shape)
    for k in range(int((hi - lo).max()) + 1):        # a loop over the band's few cells
        j = lo + k
        ok = (j <= hi) & (j >= 0) & (j < grid.n_rho)
        lin = (g[:, None] * grid.n_rho + j) * grid.n_theta + n
        acc += np.bincount(lin[ok], weights=wt[ok], minlength=size)
    return acc.reshape((n_groups,) + grid.shape)


def rho_sigma(theta, *, x, y, sigma: float = 0.0, sigma_range: float = 0.0,
              sigma_azimuth: float = 0.0, range_=None, azimuth=None) -> np.ndarray:
    """Standard deviation of rho of each point's curve at each theta (Liang et al. eq. 6).

    d rho = cos(theta - beta) dr + sin(theta - beta) r d beta for a radar at the origin
    measuring range r and azimuth beta; with independent errors
    sigma_rho^2 = cos^2(theta - beta) sigma_r^2 + sin^2(theta - beta) r^2 sigma_beta^2.
    For Cartesian errors of sigma per axis (eq. 4), sigma_rho = sigma at every theta.

    Returns
    -------
    ndarray of shape (N, n_theta)
        The two contributions added in quadrature (either may be zero).
    """
    theta = np.asarray(theta, dtype=float)
    x = np.asarray(x, float)
    out = np.full((x.size, theta.size), float(sigma) ** 2)
    if sigma_range > 0 or sigma_azimuth > 0:
        r = np.hypot(x, y) if range_ is None else np.asarray(range_, float)
        beta = np.arctan2(y, x) if azimuth is None else np.asarray(azimuth, float)
        d = theta[None, :] - beta[:, None]
        out = out + (np.cos(d) * sigma_range) ** 2 + (np.sin(d) * r[:, None] * sigma_azimuth) ** 2
    return np.sqrt(out)


def fuzzy_hough_transform(x, y, *, grid: HoughGrid, sigma_rho, support: float = 3.0,
                          max_half_width: int = 12, groups=None, n_groups: int = 1) -> np.ndarray:
    """Fuzzy accumulation (Liang et al. 2015, eq. 7-8): each point adds a Gaussian
    membership exp(-(rho_j - rho_i)^2 / (2 sigma_rho^2)) to the cells within
    ``support * sigma_rho`` of its curve in every theta column.

    Parameters
    ----------
    x, y : array_like of shape (N,)
        Points (x = column, y = row; or metres).
    grid : HoughGrid
    sigma_rho : float or ndarray of shape (N, n_theta)
        Spread of rho per point and theta column (see ``rho_sigma``). It is floored at
        half a cell, so a point at the radar (range 0, where the azimuth term vanishes) or
        an error-free point still gives a peak of 1 in its own cell, never a division by
        zero.
    support : float
        rho_m = support * sigma_rho (the paper's maximum error); k_rho = 2 rho_m / drho + 1.
    max_half_width : int
        Cap on rho_m in cells, which bounds the cost whatever sigma is.

    Returns
    -------
    ndarray of shape (n_groups, n_rho, n_theta)
        Sum of memberships; a single point's own cell gets at most 1.

    Notes
    -----
    The paper spreads the membership over theta too (k_theta = 2 theta_m / dtheta + 1).
    Every theta column already carries the point's own core rho_i(theta_n), so a theta
    spread counts each point again in neighbouring columns; we spread along rho only.
    """
    x, y = _check_points(x, y)
    g = np.zeros(x.size, np.int64) if groups is None else np.asarray(groups, np.int64).ravel()
    if x.size == 0:
        return np.zeros((n_groups,) + grid.shape)
    if not (support > 0):
        raise ValueError(f"support must be > 0, got {support}")
    s = np.broadcast_to(np.asarray(sigma_rho, float), (x.size, grid.n_theta))
    if not np.isfinite(s).all() or (s < 0).any():
        raise ValueError("sigma_rho must be finite and >= 0")
    s = np.maximum(s, 0.5 * grid.drho)
    rho = curve_rho(x, y, grid)
    pos = (rho - grid.rho_min) / grid.drho - 0.5          # fractional cell-centre index
    half = np.minimum(np.ceil(support * s / grid.drho), max_half_width).astype(np.int64)
    kmax = int(half.max())
    base = np.rint(pos).astype(np.int64)
    size = n_groups * grid.n_rho * grid.n_theta
    n = np.arange(grid.n_theta)[None, :]
    lins, mus = [], []
    for k in range(-kmax, kmax + 1):                       # a handful of offsets, vectorised
        j = base + k
        d = (j - pos) * grid.drho
        ok = (np.abs(k) <= half) & (j >= 0) & (j < grid.n_rho) & (np.abs(d) <= support * s)
        lins.append(((g[:, None] * grid.n_rho + j) * grid.n_theta + n)[ok])
        mus.append(np.exp(-0.5 * (d[ok] / s[ok]) ** 2))
    acc = np.bincount(np.concatenate(lins), weights=np.concatenate(mus), minlength=size)
    return acc.reshape((n_groups,) + grid.shape)


def parallel_combine(per_scan: np.ndarray, *, q1: float = 0.0) -> np.ndarray:
    """Parallel rule (Lu et al. 2013; Liang et al. 2015 rule 2): a cell keeps the sum of
    its accumulation vector L = [b_1 ... b_P] only when every element exceeds ``q1``.

    Parameters
    ----------
    per_scan : ndarray of shape (P, ...)
        One accumulator per scan on a common grid.
    q1 : float
        Per-scan support threshold (0 for binary parallel Hough: every scan must vote).

    Returns
    -------
    ndarray of shape per_scan.shape[1:]
        B = sum_p b_p where min_p b_p > q1, else 0.
    """
    per_scan = np.asarray(per_scan, float)
    if per_scan.shape[0] == 0:
        return np.zeros(per_scan.shape[1:])
    keep = (per_scan > q1).all(axis=0)
    return np.where(keep, per_scan.sum(axis=0), 0.0)


def nms_peaks(acc: np.ndarray, *, size: int = 3, threshold: float = 0.0) -> np.ndarray:
    """Greedy non-maximum suppression in cell units (scikit-image ``hough_line_peaks``
    style): take the strongest cell above ``threshold``, clear a ``size`` x ``size``
    neighbourhood (theta wraps with rho mirrored), repeat.

    Parameters
    ----------
    acc : ndarray of shape (n_rho, n_theta) or (G, n_rho, n_theta)
        One accumulator, or G independent ones (tiles) suppressed together.
    size : int
        Neighbourhood side in cells (odd >= 1).

    Returns
    -------
    ndarray of shape (K, 2) of int, or (K, 3) for G accumulators
        (rho index, theta index), preceded by the accumulator index for G accumulators,
        of the kept peaks, strongest first (ties: lower flat index first).

    Notes
    -----
    Computed in parallel rounds, not one peak at a time: a live cell whose rank is the
    largest among the live cells of its neighbourhood is kept by the greedy order too
    (nothing stronger near it can be kept before it, and the neighbourhood relation is
    symmetric, wrap included), so every round keeps all such cells at once and clears
    their neighbourhoods. The result is the greedy one exactly. Only the cells above
    ``threshold`` take part: their neighbour pairs are found once (sorted-index lookup),
    and each round is a segment maximum over those pairs.
    """
    if int(size) != size or size < 1:
        raise ValueError(f"size must be a positive integer, got {size}")
    a = np.asarray(acc, float)
    single = a.ndim == 2
    if single:
        a = a[None]
    if a.ndim != 3:
        raise ValueError(f"acc must have 2 or 3 dimensions, got shape {np.shape(acc)}")
    G, n_rho, n_theta = a.shape
    flat = np.flatnonzero(a > threshold)                  # candidates, ascending
    order = np.argsort(-a.ravel()[flat], kind="stable")
    strength = np.empty(flat.size, np.int64)
    strength[order] = np.arange(flat.size, 0, -1)        # strongest: largest, no ties
    g, j, n = np.unravel_index(flat, a.shape)
    # neighbour pairs between candidates (theta wraps with rho mirrored)
    h = size // 2
    ii, nb = [], []
    for dj in range(-h, h + 1):
        for dn in range(-h, h + 1):
            if dj == 0 and dn == 0:
                continue
            nn = n + dn
            wrap = (nn < 0) | (nn >= n_theta)
            jj = np.where(wrap, n_rho - 1 - (j + dj), j + dj)
            ok = (jj >= 0) & (jj < n_rho)
            key = (g * n_rho + jj) * n_theta + nn % n_theta
            pos = np.minimum(np.searchsorted(flat, key), max(flat.size - 1, 0))
            hit = ok & (flat[pos] == key) if flat.size else ok
            ii.append(np.flatnonzero(hit))
            nb.append(pos[hit])
    ii = np.concatenate(ii) if ii else np.zeros(0, np.int64)
    nb = np.concatenate(nb) if nb else np.zeros(0, np.int64)
    o = np.argsort(ii, kind="stable")
    ii, nb = ii[o], nb[o]
    has = np.unique(ii)
    starts = np.searchsorted(ii, has)
    alive = np.ones(flat.size, bool)
    kept = []
    while alive.any():
        best_nb = np.zeros(flat.size, np.int64)
        if ii.size:
            best_nb[has] = np.maximum.reduceat(np.where(alive[nb], strength[nb], 0), starts)
        sel = alive & (strength > best_nb)
        kept.append(np.flatnonzero(sel))
        alive[nb[sel[ii]]] = False
        alive[sel] = False
    idx = np.concatenate(kept) if kept else np.zeros(0, np.int64)
    idx = idx[np.argsort(-strength[idx], kind="stable")]
    out = np.column_stack([g[idx], j[idx], n[idx]]).astype(np.int64).reshape(-1, 3)
    return out[:, 1:] if single else out

