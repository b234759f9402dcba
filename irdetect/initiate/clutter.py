"""The per-track clutter test: could clutter of the density in the data have made a
constant-velocity chain at least as good as this track, anywhere in the window?

A track that passes the constant-velocity check (``irdetect.initiate.common.verify``) is
kept only when the expected number of clutter chains at least as good, over every
hypothesis the window offers, is within the user's expected false-track rate per window
(``false_tracks``; 0 turns the test off). The clutter density is measured in the data:
the measurements no accepted track explains, per scan, over the area the measurements
cover (their convex hull). Coordinates: x, y in the file's units (x = column, y = row for
images); time in s (or frames).

The equations (docs/initiation.md, "Sensor model"): with M scans in the window, the
density c of clutter points per unit area per scan, a track's error ellipse s_r x s_c
(its measurements' mean; a circle of sigma for Cartesian measurements) and gate g,

* a circle of g normalised units about a predicted position holds a clutter point with
  probability p(g) = 1 - exp(-KAPPA c pi g^2 s_r s_c) (KAPPA for the fit drawn towards
  the chain's own points);
* clutter alone gives at least n of M scans within g with probability
  B(n; M, p(g)) = sum_{k >= n} C(M, k) p^k (1 - p)^(M - k);
* the window offers H = A pi (v_max D + g0 s)^2 / (pi g0^2 s_r s_c)^2 distinct chains
  (A the area of the measurements, D the window's duration, g0 the CV check's ``gate``):
  position cells of one gate, velocity cells of one gate over D;
* a track whose fitted residuals put n_j of its measurements within g_j (levels
  g_j = ``gate`` x LEVELS) gets the look-elsewhere expectation
  E = H J min_j B(n_j; M, p(g_j)) (J levels tried: a Bonferroni factor);
* it is kept when E <= ``false_tracks``.

The separable limit: the clutter load mu = c pi gate^2 s_r s_c (clutter points per gate
per scan) at which a track of all M scans within 5/6 of the gate (a typical genuine
track: 2.5 sigma for gate 3) has E = ``false_tracks``. Beyond it no test on the
chain's points tells a target from clutter chains; ``separability`` reports both.
"""

from __future__ import annotations

import math

import numpy as np

from irdetect.initiate.base import sigma_axes

#: Gate levels tried, as fractions of ``gate`` (1.15: the CV check's refinement gate).
LEVELS = (0.5, 2 / 3, 5 / 6, 1.0, 1.15)

#: Inflation of a clutter point's chance to fall in a gate of the chain's own fit,
#: calibrated on clutter-only scenes (docs/initiation.md): at 0.15 and 0.3 clutter points
#: per gate per scan, 0.04 and 0.00 tracks per window had E <= 0.05 (1.0: 0.25 and 0.08;
#: 2.0: 20-60x fewer tracks than E said, and a lower separable limit).
KAPPA = 1.5

#: The gate level of the "typical genuine track" of the separable limit.
TYPICAL = 5 / 6


def hull_area(x, y) -> float:
    """Area covered by the points (x, y), arrays of shape (N,): their convex hull, else
    (collinear or fewer than 3 points) the bounding box; 0 when that is empty."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    if x.size >= 3:
        from scipy.spatial import ConvexHull, QhullError

        try:
            return float(ConvexHull(np.column_stack([x, y])).volume)
        except (QhullError, ValueError):
            pass
    return float(np.ptp(x) * np.ptp(y)) if x.size else 0.0


def hypotheses(area, duration, v_max, gate, s_r, s_c):
    """H, the distinct constant-velocity chains a window offers (see the module notes).

    Parameters
    ----------
    area : float
        Area of the measurements (file units^2).
    duration : float
        Time from the window's first to its last scan (s).
    v_max : float
        Largest speed (units per s; 0: the extent of the area bounds the motion).
    gate : float
        The CV check's gate (normalised units).
    s_r, s_c : ndarray of shape (T,)
        Error-ellipse axes of every track (file units).

    Returns
    -------
    ndarray of shape (T,)
        At least 1.
    """
    cell = math.pi * gate ** 2 * s_r * s_c
    reach = v_max * duration if v_max > 0 else math.sqrt(area)
    reach = np.minimum(reach, math.sqrt(area)) + gate * np.sqrt(s_r * s_c)
    return np.maximum(area * math.pi * reach ** 2 / np.maximum(cell, 1e-300) ** 2, 1.0)


def chain_expectation(hits, M, density, s_r, s_c, H, gate):
    """E, the expected clutter chains at least as good as each track (see module notes).

    Parameters
    ----------
    hits : ndarray of shape (T, J)
        Measurements of every track within ``gate`` x ``LEVELS[j]`` of its fit.
    M : int
        Scans in the window.
    density : float
        Clutter points per unit area per scan.
    s_r, s_c, H : ndarray of shape (T,)
        Error-ellipse axes and the hypotheses (``hypotheses``) of every track.
    gate : float
        The CV check's gate.

    Returns
    -------
    ndarray of shape (T,)
    """
    from scipy.special import bdtrc

    g = gate * np.asarray(LEVELS)[None, :]
    mu = KAPPA * density * math.pi * g ** 2 * (s_r * s_c)[:, None]
    p = -np.expm1(-mu)
    n = np.asarray(hits)
    tail = np.where(n >= 1, bdtrc(np.maximum(n - 1, 0), M, p), 1.0)   # P(X >= n)
    return H * len(LEVELS) * tail.min(axis=1)


def residuals(win, members, p):
    """Normalised residuals of every track's measurements to its own least-squares
    constant-velocity fit (range / cross-range terms for polar measurements).

    Returns
    -------
    e : ndarray of shape (T, K)
        Residuals, inf where padded (K the longest track).
    s_r, s_c : ndarray of shape (T,)
        Mean error-ellipse axes of every track's measurements.
    """
    from irdetect.initiate.common import _fit_error

    cnt = np.array([m.size for m in members], np.int64)
    T, K = cnt.size, int(cnt.max())
    idx = np.zeros((T, K), np.int64)
    mask = np.arange(K)[None, :] < cnt[:, None]
    idx[mask] = np.concatenate(members)
    axes = win.error_axes(idx, p)
    e = _fit_error(win.x[idx], win.y[idx], win.t[idx], mask, axes)
    e = np.where(mask, e, np.inf)
    a_r, a_c = np.broadcast_arrays(axes[2], axes[3], idx)[:2]
    s_r = np.where(mask, a_r, 0).sum(axis=1) / cnt
    s_c = np.where(mask, a_c, 0).sum(axis=1) / cnt
    return e, s_r, s_c


def clutter_test(win, members, p, rounds: int = 4):
    """Which tracks clutter of the measured density explains too easily.

    Parameters
    ----------
    win : irdetect.initiate.base.Window
        The window's measurements (x, y, t, scan index, error ellipses).
    members : list of ndarray of int
        Every candidate track's measurements (indices into the window, one per scan).
    p : dict
        Checked parameters: ``false_tracks``, ``gate``, ``v_max``, ``sigma``,
        ``sigma_range``, ``sigma_azimuth``.
    rounds : int
        Passes of the density estimate: the density counts the measurements no track
        kept so far explains (it only falls, so kept tracks stay kept).

    Returns
    -------
    keep : ndarray of bool, shape (T,)
        Tracks whose expectation E is within ``false_tracks``.
    density : float
        The clutter density the last pass used (points per unit area per scan).
    """
    T = len(members)
    M = win.n_scans
    area = hull_area(win.x, win.y)
    if T == 0 or not area > 0:
        return np.ones(T, bool), 0.0
    e, s_r, s_c = residuals(win, members, p)
    g = p["gate"] * np.asarray(LEVELS)
    hits = (e[:, :, None] <= g[None, None, :]).sum(axis=1)              # (T, J)
    duration = float(np.ptp(win.t))
    H = hypotheses(area, duration, p["v_max"], p["gate"], s_r, s_c)
    cnt = np.array([m.size for m in members])
    keep = np.zeros(T, bool)
    density = win.x.size / (M * area)
    for _ in range(rounds):
        E = chain_expectation(hits, M, density, s_r, s_c, H, p["gate"])
        new = E <= p["false_tracks"]
        if not (new & ~keep).any():
            break
        keep |= new
        density = max(win.x.size - int(cnt[keep].sum()), 0) / (M * area)
    return keep, density


def separability(x, y, t, n_scans, p, *, range_=None, explained: int = 0):
    """The clutter load of a window against the separable limit.

    Parameters
    ----------
    x, y, t : ndarray of shape (N,)
        The window's measurements (file units, s).
    n_scans : int
        Scans in the window (M).
    p : dict
        Checked parameters (``false_tracks``, ``gate``, ``v_max``, ``sigma``,
        ``sigma_range``, ``sigma_azimuth``).
    range_ : ndarray of shape (N,), optional
        Measured ranges of polar measurements (their error ellipses grow with range).
    explained : int
        Measurements held by the window's tracks (not clutter).

    Returns
    -------
    load, limit : float
        Clutter points per gate (``gate`` sigma ellipse) per scan, measured and at the
        limit (see the module notes); (0, inf) when the test is off or the area empty.
    """
    area = hull_area(x, y)
    if not (p["false_tracks"] > 0 and area > 0 and n_scans >= 2):
        return 0.0, math.inf
    s_r, s_c = sigma_axes(p, range_)
    s_r, s_c = np.array([np.median(s_r)]), np.array([np.median(s_c)])
    cell = float(math.pi * p["gate"] ** 2 * s_r[0] * s_c[0])
    H = hypotheses(area, float(np.ptp(t)), p["v_max"], p["gate"], s_r, s_c)
    load = max(len(x) - explained, 0) / (n_scans * area) * cell
    # bisection on log(load): E of a full track within TYPICAL x gate equals false_tracks
    hits = np.zeros((1, len(LEVELS)), np.int64)
    hits[0, np.asarray(LEVELS) >= TYPICAL - 1e-9] = n_scans
    lo, hi = -40.0, 10.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        E = chain_expectation(hits, n_scans, math.exp(mid) / cell, s_r, s_c, H,
                              p["gate"])[0]
        lo, hi = (mid, hi) if E <= p["false_tracks"] else (lo, mid)
    return load, math.exp(lo)


def can_pass(win, p) -> bool:
    """Whether any track of the window could pass ``clutter_test``: False when even the
    best chain there can be (all M scans within ``LEVELS[0]`` x gate, the smallest error
    ellipse of the window) has E > ``false_tracks`` at the density of the first pass
    (every measurement counted). The initiators then skip the window: the test would
    reject every track it found (past the separable limit this saves all the work).
    """
    if not (p["verify"] and p["false_tracks"] > 0) or win.x.size == 0:
        return True
    area = hull_area(win.x, win.y)
    if not area > 0:
        return True
    s_r, s_c = np.broadcast_arrays(*win.error_axes(np.arange(win.x.size), p)[2:])
    k = int(np.argmin(s_r * s_c))
    s_r, s_c = np.array([float(s_r[k])]), np.array([float(s_c[k])])
    M = win.n_scans
    H = hypotheses(area, float(np.ptp(win.t)), p["v_max"], p["gate"], s_r, s_c)
    hits = np.full((1, len(LEVELS)), M)
    E = chain_expectation(hits, M, win.x.size / (M * area), s_r, s_c, H, p["gate"])
    return bool(E[0] <= p["false_tracks"])
