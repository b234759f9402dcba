"""The constant-velocity check of a cell's supporting measurements and the merging of
tracks across initiation windows (shared by every Hough method and the image pipeline).

Coordinates: x = column, y = row (pixels) for images, the file's units for scans; time in
frames or seconds.
"""

from __future__ import annotations

import math

import numpy as np

from irdetect.initiate.base import ROW, Window, expand, min_points


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
    rows = np.zeros(len(groups), ROW)
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



def verify(win: Window, ptr, mem, theta, p, max_members: int = 64):
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
    need = min_points(win, p)
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


def _cv_batch(win: Window, ptr, mem, cells, theta, K, p, max_tracks: int = 4):
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
    idx[rows, cols] = mem[expand(start, cnt)]
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
    need = min_points(win, p)
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


