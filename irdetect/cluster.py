"""Subtractive clustering (Chiu 1994) with MATLAB ``subclust`` semantics.

Used to merge the Hough cells that crowd around one true line ("peak clustering",
Zhang, Su & Ma 2010, section 2) into one cluster centre per track.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Clusters:
    """Result of ``subtractive_cluster``.

    Attributes
    ----------
    centres : ndarray of shape (K, D)
        Cluster centres, in the input units (each is one of the data points).
    index : ndarray of shape (K,) of int
        Row of each centre in the input.
    potential : ndarray of shape (K,)
        Potential of each centre when it was accepted (the first is the highest).
    labels : ndarray of shape (N,) of int
        Nearest centre of every point (scaled distance), -1 when there is no centre (or
        with ``labels=False``).
    """

    centres: np.ndarray
    index: np.ndarray
    potential: np.ndarray
    labels: np.ndarray


def subtractive_cluster(x, *, radii=0.5, squash: float = 1.25, accept_ratio: float = 0.5,
                        reject_ratio: float = 0.15, bounds=None, weights=None,
                        wrap_lines: bool = False, groups=None, labels: bool = True) -> Clusters:
    """Find cluster centres by subtractive clustering, as MATLAB ``subclust`` does.

    Every point gets the potential P_i = sum_j w_j exp(-4 |x_i - x_j|^2 / r_a^2) (Zhang et
    al. eq. 3 in Chiu's form: the paper prints (gamma_a / 2) without the square; r_a =
    gamma_a). The highest potential P* is the first centre; after each accepted centre c,
    P_i <- P_i - P_c exp(-4 |x_i - c|^2 / r_b^2) with r_b = squash * r_a (eq. 4-6). The next
    highest point c is
      * accepted when P_c / P* > accept_ratio,
      * in the grey zone (reject_ratio < P_c / P* <= accept_ratio) accepted only when
        d_min + P_c / P* >= 1, d_min its scaled distance to the nearest centre; otherwise
        its potential is set to 0 and the search goes on,
      * the end when P_c / P* <= reject_ratio.
    The paper's rule (stop when D_ck / D_c1 < delta, eq. 5) is the special case
    accept_ratio = reject_ratio = delta.

    Parameters
    ----------
    x : array_like of shape (N, D)
        Data points.
    radii : float or array_like of shape (D,)
        Range of influence r_a per dimension, as a fraction of the unit box.
    squash : float
        r_b / r_a (> 0; MATLAB's default 1.25; the paper requires gamma_b > gamma_a).
    accept_ratio, reject_ratio : float
        In (0, 1], reject_ratio <= accept_ratio.
    bounds : array_like of shape (2, D), optional
        Minimum and maximum of each dimension used to normalise the data to the unit box;
        default the data's own minimum and maximum (MATLAB's default). A dimension of zero
        extent is left unscaled.
    weights : array_like of shape (N,), optional
        Weight of each point in the potentials (default 1; MATLAB has none).
    wrap_lines : bool
        Columns 0 and 1 are (rho, theta) of lines with theta in [0, pi): the distance
        between two points is the smaller of the direct one and the one to the same
        line written as (-rho, theta -/+ pi), so lines near theta = 0 and theta = pi
        cluster together. Requires bounds symmetric in rho and spanning pi in theta
        (given or derived: rho in [-max|rho|, max|rho|], theta in [0, pi]).
    groups : array_like of int, shape (N,), optional
        Independent problems solved together (e.g. the Hough candidates of every spatial
        tile): points of different groups never interact, each group has its own P*, and
        the result is what separate calls per group would give (centres of all groups
        together, in the order they were accepted). Default: one group.
    labels : bool
        Compute ``Clusters.labels`` (False leaves them -1, saving a nearest-centre search).

    Returns
    -------
    Clusters

    Raises
    ------
    ValueError
        Bad shapes, NaN data, or parameters outside their ranges.

    Examples
    --------
    >>> import numpy as np
    >>> pts = np.array([[0.0, 0.0], [0.1, 0.0], [5.0, 5.0], [5.1, 5.0]])
    >>> subtractive_cluster(pts, radii=0.3).centres.shape[0]
    2
    """
    x = np.asarray(x, dtype=float)
    if x.ndim == 1:
        x = x[:, None]
    if x.ndim != 2:
        raise ValueError(f"x must have shape (N, D), got {x.shape}")
    n, d = x.shape
    if not np.isfinite(x).all():
        raise ValueError("x holds NaN or inf")
    r = np.broadcast_to(np.asarray(radii, float), (d,)).copy()
    if not (np.isfinite(r).all() and (r > 0).all()):
        raise ValueError(f"radii must be > 0, got {radii}")
    if not squash > 0:
        raise ValueError(f"squash must be > 0, got {squash}")
    if not (0 < reject_ratio <= accept_ratio <= 1):
        raise ValueError(f"need 0 < reject_ratio <= accept_ratio <= 1, got "
                         f"reject_ratio={reject_ratio}, accept_ratio={accept_ratio}")
    w = np.ones(n) if weights is None else np.asarray(weights, float).ravel()
    if w.shape != (n,) or not np.isfinite(w).all() or (w < 0).any():
        raise ValueError("weights must be N finite values >= 0")
    g = np.zeros(n, np.int64) if groups is None else np.asarray(groups).ravel()
    if g.shape != (n,) or (n and not np.issubdtype(g.dtype, np.integer)):
        raise ValueError("groups must be N integers")
    if wrap_lines and d < 2:
        raise ValueError("wrap_lines needs columns (rho, theta)")
    if n == 0:
        return Clusters(np.zeros((0, d)), np.zeros(0, np.int64), np.zeros(0),
                        np.zeros(0, np.int64))
    if bounds is None:
        lo, hi = x.min(axis=0), x.max(axis=0)
        if wrap_lines:
            m = np.abs(x[:, 0]).max()
            lo[0], hi[0], lo[1], hi[1] = -m, m, 0.0, np.pi
    else:
        lo, hi = (np.asarray(b, float) for b in np.asarray(bounds, float))
        if lo.shape != (d,) or hi.shape != (d,):
            raise ValueError(f"bounds must have shape (2, {d})")
    span = np.where(hi - lo > 0, hi - lo, 1.0)
    u = (x - lo) / span
    mirror = None
    if wrap_lines:
        # The same line written as (-rho, theta - pi): in unit-box coordinates with a
        # symmetric rho range, rho -> 1 - u_rho and theta -> u_theta - 1 (pi / span).
        mirror = u.copy()
        mirror[:, 0] = 1.0 - u[:, 0]
        mirror[:, 1] = u[:, 1] - np.pi / span[1]
    return _subclust(u, x, r, squash, accept_ratio, reject_ratio, w, mirror, g, labels)


def _csr_positions(starts, counts):
    """Concatenated ranges [starts[i], starts[i] + counts[i])."""
    return np.repeat(starts - np.cumsum(np.r_[0, counts[:-1]]), counts) + np.arange(counts.sum())


def _subclust(u, x, r, squash, accept, reject, w, mirror, groups, want_labels=True,
              cutoff: float = 2.0):
    """Kernel on unit-box data u, every group at once.

    Only pairs within ``cutoff`` radii count (exp(-4 * 2^2) ~ 1e-7 of a point's own
    share; the subtraction reaches ``cutoff`` r_b). One KD-tree over the points, with
    the group as an extra coordinate far beyond the cut-off so groups never interact,
    gives the neighbour graph once (``_pair_graph``); the
    centre search then runs all groups in lock step: each pass takes the highest
    remaining potential of every group still searching, so the number of passes is
    the largest number of centres of one group, not the number of groups.
    """
    from scipy.spatial import cKDTree

    n = len(u)
    reach = cutoff * max(1.0, squash)           # subtraction reaches squash radii further
    sep = np.asarray(groups, float)[:, None] * (10.0 * reach + 10.0)
    z = u / r                                   # unit radius of influence
    views = [z]
    if mirror is not None:
        zm = mirror / r
        zp = zm.copy()
        zp[:, 1] = 2 * z[:, 1] - zm[:, 1]
        views += [zm, zp]
    # a theta range so short (against the radius) that one pair can be near through two
    # views: each pair keeps its smallest distance (the line-wrap rule)
    short = len(views) > 1 and (mirror[0, 1] - u[0, 1]) ** 2 / r[1] ** 2 < (2 * reach) ** 2
    ii, jj, dd = _pair_graph(z, sep, views, reach, short)
    pot = _potentials(ii, jj, dd, w, n, cutoff)
    # neighbour lists of every point (CSR over ii) for the subtraction: -4 d^2 / squash^2
    ptr = np.searchsorted(ii, np.arange(n + 1))
    g_ids, g_of = np.unique(groups, return_inverse=True)
    G = g_ids.size
    by_group = np.argsort(g_of, kind="stable")
    starts = np.searchsorted(g_of[by_group], np.arange(G))
    ref = np.maximum.reduceat(pot[by_group], starts)
    searching = ref > 0
    centres: list[np.ndarray] = []
    cpot: list[np.ndarray] = []
    is_centre = np.zeros(n, bool)
    while searching.any():
        # highest potential of every group (first index on ties, as np.argmax)
        ps = pot[by_group]
        gmax = np.maximum.reduceat(ps, starts)
        hit = np.flatnonzero(ps == gmax[g_of[by_group]])
        gg, first_hit = np.unique(g_of[by_group][hit], return_index=True)
        k = by_group[hit[first_hit]]
        live = searching[gg]
        gg, k = gg[live], k[live]
        pk = pot[k]
        ratio = np.where(ref[gg] > 0, pk / np.where(ref[gg] > 0, ref[gg], 1.0), 0.0)
        stop = (pk <= 0) | (ratio <= reject)
        searching[gg[stop]] = False
        grey = ~stop & (ratio <= accept)
        take = ~stop & ~grey
        if grey.any():
            # distance to the nearest centre of the group: centres beyond the graph's
            # reach (>= 3 radii) cannot fail dmin + ratio >= 1, so the graph suffices
            kg = k[grey]
            cg = ptr[kg + 1] - ptr[kg]
            pos = _csr_positions(ptr[kg], cg)
            owner = np.repeat(np.arange(kg.size), cg)
            hit = is_centre[jj[pos]]
            dmin = np.full(kg.size, np.inf)
            np.minimum.at(dmin, owner[hit], dd[pos[hit]])
            ok = dmin + ratio[grey] >= 1.0
            pot[kg[~ok]] = 0.0
            take[np.flatnonzero(grey)[ok]] = True
        if not take.any():
            continue
        kt, pt = k[take], pk[take]
        centres.append(kt)
        cpot.append(pt)
        is_centre[kt] = True
        # subtract P_c exp(-4 |x - c|^2 / r_b^2) around every new centre (groups disjoint)
        cnt = ptr[kt + 1] - ptr[kt]
        pos = _csr_positions(ptr[kt], cnt)
        js = jj[pos]
        sub = np.exp(-4.0 * (dd[pos] / squash) ** 2)
        pot[js] = np.maximum(pot[js] - np.repeat(pt, cnt) * sub, 0.0)
        pot[kt] = 0.0
    idx = np.concatenate(centres) if centres else np.zeros(0, np.int64)
    pots = np.concatenate(cpot) if cpot else np.zeros(0)
    labels = np.full(n, -1, np.int64)
    if idx.size and want_labels:
        # nearest centre of the same group (scaled distance, wrap-aware)
        ctree = cKDTree(np.hstack([z[idx], sep[idx]]))
        best = np.full(n, np.inf)
        for v in views:
            d, j = ctree.query(np.hstack([v, sep]))
            better = d < best
            best[better], labels[better] = d[better], j[better]
    return Clusters(x[idx], idx, pots, labels)


def _pair_graph(z, sep, views, reach, short):
    """Neighbour pairs (i, j, distance) with |z_i - view(z_j)| <= ``reach``, sorted by i.

    ``z`` (n, d) scaled points, ``sep`` (n, 1) the group coordinate, ``views`` the
    point sets j is taken from (z and, for wrapped lines, its two mirrors). A pair found
    through several views keeps its smallest distance when ``short`` (a theta range so
    short against the radius that this can happen); otherwise the views' pairs are
    concatenated, each i's in the order found. Indices are int32 and each view's pairs
    are converted as they come: the graph is most of the clustering's memory.
    """
    from scipy.spatial import cKDTree

    n = len(z)
    tree = cKDTree(np.hstack([z, sep]))
    ii, jj, dd = [], [], []
    for v in views:
        sd = tree.sparse_distance_matrix(cKDTree(np.hstack([v, sep])), reach,
                                         output_type="ndarray")
        ii.append(sd["i"].astype(np.int32)), jj.append(sd["j"].astype(np.int32))
        dd.append(sd["v"])
        del sd
    ii, jj, dd = np.concatenate(ii), np.concatenate(jj), np.concatenate(dd)
    if short:
        key = ii.astype(np.int64) * n + jj
        order = np.lexsort((dd, key))
        first = np.r_[True, key[order][1:] != key[order][:-1]]
        order = order[first]
    else:
        order = np.argsort(ii, kind="stable")
    ii, jj, dd = ii[order], jj[order], dd[order]
    # self pairs (distance 0) are in the graph whatever sparse_distance_matrix does
    self_missing = np.setdiff1d(np.arange(n, dtype=np.int32), ii[ii == jj])
    if self_missing.size:
        ii = np.r_[ii, self_missing]
        jj = np.r_[jj, self_missing]
        dd = np.r_[dd, np.zeros(self_missing.size)]
        o = np.argsort(ii, kind="stable")
        ii, jj, dd = ii[o], jj[o], dd[o]
    return ii, jj, dd


#: pairs per block of ``_potentials`` (blocks end between two points' pairs)
POT_BLOCK = 1 << 22


def _potentials(ii, jj, dd, w, n, cutoff):
    """Every point's potential sum_j w_j exp(-4 d_ij^2) over its pairs within ``cutoff``
    (``ii`` sorted), in blocks of whole points' pairs: each point's sum is added in the
    same order as one pass over all pairs, so the values are the same to the bit."""
    pot = np.zeros(n)
    lo = 0
    while lo < len(ii):
        hi = min(len(ii), lo + POT_BLOCK)
        if hi < len(ii):
            hi = int(np.searchsorted(ii, ii[hi], side="left"))
            if hi <= lo:                                # one point with > POT_BLOCK pairs
                hi = int(np.searchsorted(ii, ii[lo], side="right"))
        i, j, d = ii[lo:hi], jj[lo:hi], dd[lo:hi]
        near = d <= cutoff
        pot += np.bincount(i[near], weights=np.exp(-4.0 * d[near] ** 2) * w[j[near]],
                           minlength=n)
        lo = hi
    return pot
