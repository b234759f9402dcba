"""Fuzzy c-means: memberships to given centres, and the full Bezdek iteration.

The tracker uses :func:`fcm_memberships` with the centres fixed at the predicted tracks
(Cheng et al., step 3); :func:`fcm` is the complete algorithm of the paper's section 1
(random memberships, alternate centre / membership updates until the centres settle),
kept for clustering and as the reference the membership formula is tested against.
"""

from __future__ import annotations

import numpy as np


def fcm_memberships(distances: np.ndarray, *, m: float = 2.0,
                    noise_distance: float | None = None) -> np.ndarray:
    """Fuzzy c-means memberships of points to fixed centres.

    Parameters
    ----------
    distances : ndarray of shape (C, N)
        Distance of point k (column) to centre i (row); non-negative, ``inf`` for "not a
        candidate" (outside the gate).
    m : float
        Fuzzifier, > 1 (the paper's exponent m; 2 by default).
    noise_distance : float, optional
        Distance of every point to an extra *noise* cluster (Dave 1991). When given, the
        result has C + 1 rows and the last row is the membership of each point to "none of
        the centres"; a point far from every centre then belongs to the noise row.

    Returns
    -------
    ndarray of shape (C, N) or (C + 1, N)
        Memberships u_ik in [0, 1]; every column sums to 1 (a column with no finite
        distance and no noise cluster is all zero).

    Notes
    -----
    Bezdek's update (the paper's eq. 4)::

        u_ik = 1 / sum_j (d_ik / d_jk) ** (2 / (m - 1))

    with u_ik = 1 (and 0 elsewhere) when d_ik = 0; several zero distances share the
    membership equally. The paper has no noise cluster; we add one because with a single
    track every region would otherwise belong to it with membership 1.
    """
    d = np.asarray(distances, dtype=float)
    if d.ndim != 2:
        raise ValueError(f"distances must be 2-D (C, N), got shape {d.shape}")
    if not m > 1:
        raise ValueError(f"m must be > 1, got {m!r}")
    if np.any(d < 0) or np.any(np.isnan(d)):
        raise ValueError("distances must be non-negative and not NaN")
    if noise_distance is not None:
        if not noise_distance > 0:
            raise ValueError(f"noise_distance must be > 0, got {noise_distance!r}")
        d = np.vstack([d, np.full((1, d.shape[1]), float(noise_distance))])
    return _memberships(d, m)


def _memberships(d: np.ndarray, m: float) -> np.ndarray:
    u = np.zeros_like(d)
    if d.size == 0:
        return u
    zero = d == 0
    has_zero = zero.any(axis=0)
    with np.errstate(divide="ignore"):
        w = np.where(np.isinf(d), 0.0, d ** (-2.0 / (m - 1.0)))
    w[:, has_zero] = zero[:, has_zero]
    total = w.sum(axis=0)
    ok = total > 0
    u[:, ok] = w[:, ok] / total[ok]
    return u


def fcm(data: np.ndarray, c: int, *, m: float = 2.0, tol: float = 1e-6, max_iter: int = 300,
        init: np.ndarray | None = None,
        rng: np.random.Generator | int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Fuzzy c-means clustering (Bezdek), the paper's steps 1-5.

    Parameters
    ----------
    data : ndarray of shape (N, S)
        N points with S features each.
    c : int
        Number of clusters, 1 <= c <= N.
    m : float
        Fuzzifier, > 1.
    tol : float
        Stop when the largest centre move is below ``tol``.
    max_iter : int
        Iteration cap.
    init : ndarray of shape (c, N), optional
        Initial memberships (columns are normalised); random when not given.
    rng : numpy.random.Generator or int or None
        Seeds the random initial membership matrix.

    Returns
    -------
    centres : ndarray of shape (c, S)
    u : ndarray of shape (c, N)
        Final memberships (columns sum to 1).

    Notes
    -----
    Centres v_i = sum_k u_ik^m x_k / sum_k u_ik^m (eq. 3); memberships by eq. 4 (see
    :func:`fcm_memberships`). Objective J_m = sum_i sum_k u_ik^m |x_k - v_i|^2.
    """
    x = np.asarray(data, dtype=float)
    if x.ndim != 2 or len(x) == 0:
        raise ValueError(f"data must be a non-empty (N, S) array, got shape {x.shape}")
    if not 1 <= c <= len(x):
        raise ValueError(f"c must be in [1, {len(x)}], got {c!r}")
    if not m > 1:
        raise ValueError(f"m must be > 1, got {m!r}")
    if init is None:
        u = np.random.default_rng(rng).random((c, len(x)))
    else:
        u = np.array(init, dtype=float)
        if u.shape != (c, len(x)) or np.any(u < 0):
            raise ValueError(f"init must be non-negative of shape {(c, len(x))}, got {u.shape}")
    u /= u.sum(axis=0)
    centres = _centres(x, u, m)
    for _ in range(max_iter):
        d = np.linalg.norm(x[None, :, :] - centres[:, None, :], axis=2)
        u = _memberships(d, m)
        new = _centres(x, u, m)
        moved = np.max(np.abs(new - centres))
        centres = new
        if moved < tol:
            break
    return centres, u


def _centres(x: np.ndarray, u: np.ndarray, m: float) -> np.ndarray:
    um = u ** m
    return um @ x / um.sum(axis=1, keepdims=True)
