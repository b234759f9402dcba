"""Sequential M-of-N track initiation (MATLAB ``trackHistoryLogic``) with a velocity gate.

Every measurement not taken by a track of two or more hits starts a tentative track; a
track is confirmed with ``confirm_m`` hits in its first ``confirm_n`` scans. No Kalman
filter: the gate comes from the two-point velocity error. Vectorised over tracks with a
KD-tree per scan (one pass per scan).
"""

from __future__ import annotations

import numpy as np

from irdetect.initiate.base import Window, finish
from irdetect.initiate.clutter import can_pass, clutter_test

#: The methods of this module.
METHODS = ("mn-logic",)


def initiate(points, *, params):
    """Tracks of one window by M-of-N logic (the contract of ``irdetect.initiate``;
    parameters and returns as ``irdetect.initiate.hough_sc.initiate``)."""
    win = Window.from_points(points, params)
    if not can_pass(win, {**params, "verify": True}):     # the test would reject them all
        return finish(win, [], None, None, None, None, params)
    members = confirm_tracks(win, params)
    if params["false_tracks"] > 0 and members:
        # the per-track clutter test (irdetect.initiate.clutter)
        ok, _ = clutter_test(win, members, params)
        members = [m for m, k in zip(members, ok) if k]
    n = len(members)
    return finish(win, members, np.zeros(n, np.int64), np.zeros(n), np.zeros(n),
                  np.array([m.size for m in members], float), params)


def confirm_tracks(win: Window, p):
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
