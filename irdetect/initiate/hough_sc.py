"""Hough transform track initiation with subtractive clustering (Zhang, Su & Ma 2010) and
the other single-accumulator selections: plain threshold (``hough``), greedy non-maximum
suppression (``nms``) and OpenCV's ``HoughLinesPointSet`` (``opencv``).

Every measurement (x_i, y_i) votes along rho = x cos(theta) + y sin(theta) on the cell
centres theta_n = (n - 1/2) pi / N_theta (Zhang eq. 2); every cell with at least
T = ceil(``vote_fraction`` x scans) votes is a candidate; ``hough-sc`` clusters the
candidates' (rho, theta) by subtractive clustering (Chiu's form, MATLAB ``subclust``
stop rule), one track per centre. The supporting measurements of each selected cell then
go through the constant-velocity check (``irdetect.initiate.common.verify``) unless
``verify=False`` (the paper's form: every selected cell is a track).

References
----------
Zhang, Su & Ma (2010), Hough transform track initiation algorithm based on subtractive
clustering.
"""

from __future__ import annotations

import math

import numpy as np

from irdetect.cluster import subtractive_cluster
from irdetect.hough import hough_transform, nms_peaks
from irdetect.initiate.base import Window, dedupe, finish, support, vote_threshold
from irdetect.initiate.clutter import can_pass, clutter_test
from irdetect.initiate.common import verify

#: The methods of this module.
METHODS = ("hough-sc", "hough", "nms", "opencv")


def initiate(points, *, params):
    """Tracks of one window by a single Hough accumulator (the contract of
    ``irdetect.initiate``).

    Parameters
    ----------
    points : structured ndarray
        ``irdetect.initiate.base.POINT`` rows of at least two scans (x = column, y = row
        in px, or the scans' units; t in frames or s).
    params : dict
        Every key of ``irdetect.initiate.DEFAULTS``, checked (``check_params``);
        ``params["method"]`` one of ``METHODS``.

    Returns
    -------
    rows : structured ndarray
        ``irdetect.initiate.base.ROW``, one per track.
    members : list of ndarray of int
        Indices into ``points`` of every track's measurements.
    """
    win = Window.from_points(points, params)
    if not can_pass(win, params):            # the clutter test would reject every track
        return finish(win, [], None, None, None, None, params)
    acc = hough_transform(win.lx, win.ly, grid=win.grid, groups=win.grp, n_groups=win.n_groups,
                          band=params["vote_band"] * win.sigma[win.pt])
    thr = vote_threshold(params["vote_fraction"], win.n_scans)
    # a track needs as many scans as a cell needs votes (its CV check drops outliers)
    params = {**params, "min_hits": max(params["min_hits"], (thr - 1e-9) / win.n_scans)}
    return tracks_from_accumulator(win, acc, thr, params)


def tracks_from_accumulator(win: Window, acc, thr, p):
    """Selected cells -> supporting measurements -> (CV check) -> de-duplicated rows.

    ``acc`` has shape (n_groups, n_rho, n_theta) on ``win.grid``; cells at ``thr`` or
    more are candidates. Shared by the parallel methods (``irdetect.initiate.parallel``).
    """
    g, rho, theta, value = select_peaks(win, acc, thr, p)
    ptr, mem = support(win, g, rho, theta, p)
    if p["verify"]:
        src, members = verify(win, ptr, mem, theta, p)
    else:
        src = np.flatnonzero(np.diff(ptr) >= 2)
        members = [mem[ptr[i]:ptr[i + 1]] for i in src]
    keep = dedupe(members, g[src], value[src], win, within=p["verify"])
    if p["verify"] and p["false_tracks"] > 0 and keep:
        # the per-track clutter test (irdetect.initiate.clutter)
        ok, _ = clutter_test(win, [members[i] for i in keep], p)
        keep = [i for i, k in zip(keep, ok) if k]
    src = src[keep]
    return finish(win, [members[i] for i in keep], g[src], rho[src], theta[src], value[src], p)


def select_peaks(win: Window, acc, thr, p):
    """Selected cells of every tile: arrays group, rho (tile-local), theta, value.

    ``hough`` and the parallel methods keep every candidate; ``hough-sc`` (and
    ``merge_peaks=True``) cluster the candidates of every tile in one call; ``nms``
    greedy non-maximum suppression; ``opencv`` ``cv2.HoughLinesPointSet``.
    """
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


def _opencv_peaks(win: Window, acc, thr, p):
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
