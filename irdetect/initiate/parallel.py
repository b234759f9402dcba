"""Parallel Hough (Lu et al. 2013) and fuzzy parallel Hough (Liang, Wang & Guo 2015)
track initiation.

One accumulator B_p per scan p on one grid; a cell counts only when every scan supports
it: ``parallel-hough`` votes 0/1 and keeps the cells at ``parallel_fraction`` x the peak
of the rule's total or more; ``fuzzy-parallel-hough`` adds a Gaussian membership
exp(-(rho_j - rho_i)^2 / (2 sigma_rho^2)) per measurement (eq. 6-8; sigma_rho from the
range / azimuth errors for polar measurements), applies the rule B_ij,p > ``q1`` on every
scan (eq. 7) and keeps the cells at ``q2`` x the peak or more. With ``merge_peaks`` the
cells of a peak are merged by subtractive clustering (``irdetect.initiate.hough_sc``).
Support recovery, the CV check and the rows are those of every Hough method.

References
----------
Liang, Wang & Guo (2015), Parallel Hough transform track initiation based on fuzzy
accumulation. Lu et al. (2013), parallel Hough transform track initiation.
"""

from __future__ import annotations

import numpy as np

from irdetect.hough import fuzzy_hough_transform, hough_transform
from irdetect.initiate.base import Window, finish
from irdetect.initiate.clutter import can_pass
from irdetect.initiate.hough_sc import tracks_from_accumulator

#: The methods of this module.
METHODS = ("parallel-hough", "fuzzy-parallel-hough")


def initiate(points, *, params):
    """Tracks of one window by the (fuzzy) parallel Hough rule (the contract of
    ``irdetect.initiate``; parameters and returns as ``irdetect.initiate.hough_sc.initiate``).
    """
    win = Window.from_points(points, params)
    if not can_pass(win, params):            # the clutter test would reject every track
        return finish(win, [], None, None, None, None, params)
    acc, thr = accumulate(win, params)
    return tracks_from_accumulator(win, acc, thr, params)


def accumulate(win: Window, p):
    """The rule's accumulator, shape (n_groups, n_rho, n_theta), and its threshold."""
    grid = win.grid
    scan_of = win.sidx[win.pt]
    fuzzy = p["method"] == "fuzzy-parallel-hough"
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
