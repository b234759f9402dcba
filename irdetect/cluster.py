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
        Nearest centre of every point (scaled distance), -1 when there is no centre.
    """

    centres: np.ndarray
    index: np.ndarray
    potential: np.ndarray
    labels: np.ndarray


def subtractive_cluster(x, *, radii=0.5, squash: float = 1.25, accept_ratio: float = 0.5,
                        reject_ratio: float = 0.15, bounds=None, weights=None,
                        wrap_lines: bool = False) -> Clusters:
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
    return _subclust(u, x, r, squash, accept_ratio, reject_ratio, w, mirror)


def _sq_dist(u, v, scale, mirror_v=None):
    """Scaled squared distances between rows of u (M, D) and v (K, D), wrap-aware."""
    def sq(a, b):
        out = np.zeros((len(a), len(b)))
        for k in range(a.shape[1]):            # per dimension: no (M, K, D) temporary
            out += np.subtract.outer(a[:, k] / scale[k], b[:, k] / scale[k]) ** 2
        return out

    dd = sq(u, v)
    if mirror_v is not None:
        m = mirror_v.copy()
        np.minimum(dd, sq(u, m), out=dd)              # theta - pi
        m[:, 1] = 2 * v[:, 1] - mirror_v[:, 1]
        np.minimum(dd, sq(u, m), out=dd)              # theta + pi
    return dd


def _subclust(u, x, r, squash, accept, reject, w, mirror, cutoff: float = 3.0):
    """Kernel on unit-box data u. Potentials use only pairs within ``cutoff`` radii
    (exp(-4 * 3^2) < 1e-15 of a point's own share), found with a KD-tree, so thousands of
    Hough cells cluster in well under a second."""
    from scipy.spatial import cKDTree

    z = u / r                                   # unit radius of influence
    views = [z]
    if mirror is not None:
        zm = mirror / r
        zp = zm.copy()
        zp[:, 1] = 2 * z[:, 1] - zm[:, 1]
        views += [zm, zp]
    tree = cKDTree(z)
    # pairs (i, j) with |z_i - view(z_j)| <= cutoff; a pair found through several views
    # keeps its smallest distance (the line-wrap rule)
    ii, jj, dd = [], [], []
    for v in views:
        sd = tree.sparse_distance_matrix(cKDTree(v), cutoff, output_type="ndarray")
        ii.append(sd["i"]), jj.append(sd["j"]), dd.append(sd["v"])
    ii, jj, dd = np.concatenate(ii), np.concatenate(jj), np.concatenate(dd)
    key = ii.astype(np.int64) * len(z) + jj
    order = np.lexsort((dd, key))
    first = np.r_[True, key[order][1:] != key[order][:-1]]
    ii, jj, dd = ii[order][first], jj[order][first], dd[order][first]
    pot = np.bincount(ii, weights=np.exp(-4.0 * dd ** 2) * w[jj], minlength=len(z))
    ref = pot.max()
    centres: list[int] = []
    cpot: list[float] = []
    rb = squash * r
    while ref > 0:
        k = int(np.argmax(pot))
        pk = pot[k]
        if pk <= 0:
            break
        ratio = pk / ref
        if ratio > accept:
            pass
        elif ratio > reject:
            dmin = np.sqrt(_sq_dist(u[k:k + 1], u[centres], r,
                                    None if mirror is None else mirror[centres]).min())
            if dmin + ratio < 1.0:
                pot[k] = 0.0
                continue
        else:
            break
        centres.append(k)
        cpot.append(pk)
        # only points within cutoff * squash radii of the centre (any view) change
        near = np.unique(np.concatenate(
            [np.asarray(tree.query_ball_point(v[k], cutoff * squash), np.int64)
             for v in views]))
        dk = _sq_dist(u[near], u[k:k + 1], rb, None if mirror is None else mirror[k:k + 1])[:, 0]
        pot[near] = np.maximum(pot[near] - pk * np.exp(-4.0 * dk), 0.0)
    idx = np.array(centres, dtype=np.int64)
    if idx.size:
        dc = _sq_dist(u, u[idx], r, None if mirror is None else mirror[idx])
        labels = np.argmin(dc, axis=1)
    else:
        labels = np.full(len(u), -1, np.int64)
    return Clusters(x[idx], idx, np.array(cpot), labels)
