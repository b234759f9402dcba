"""Bidirectional inter-frame correlation over 3 combined frames (Wan & Askar 2008, section 4).

A fused point of combined frame 1 starts a 3-point segment when a fused point of frame 2
lies within the motion bound l1 of it and a fused point of frame 3 lies within l2 of that
one (forward, eq. 5); the same search from frame 3 back to frame 1 is the backward
coefficient (eq. 6). Points on a segment are confirmed; the segment gives the velocity
v = s / t (eq. 8). With ``evidence``, the chains then go through irdetect's verification
(``irdetect.verify``) before the one-to-one resolution.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from irdetect.tables import SEGMENT, empty
from irdetect.verify import Evidence, verify_tracks

RESOLVE = ("all", "unique", "cost")

#: score units worth the full ``max_deviation`` in the "cost" resolution: the cost of a
#: segment is deviation / max_deviation - mean score / SCORE_SCALE
SCORE_SCALE = 2.0


@dataclass(frozen=True)
class Correlation:
    """The 3-point segments found over combined frames (k, k+1, k+2).

    Attributes
    ----------
    segments : ndarray of dtype ``irdetect.tables.SEGMENT``
        One row per segment; ``segment_id`` and ``combined_frame`` are 0 (the pipeline
        numbers them), ``vx``, ``vy`` in px/frame, ``score`` the mean of the 3 points'
        scores (0 when the inputs carry none).
    index : ndarray of int64 of shape (n_segments, 3)
        Row of each segment's point in the 1st, 2nd and 3rd input.
    """

    segments: np.ndarray
    index: np.ndarray
    #: (n_segments, 3, 2) target position (x, y) of each segment at each input's
    #: ``Evidence.report`` time, from the verified straight track; NaN without evidence
    positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 2)))
    #: (n_segments,) the verification statistic (``track_significance``); NaN without evidence
    significance: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def confirmed(self, which: int, n: int) -> np.ndarray:
        """Bool mask over the ``n`` points of input ``which`` (0, 1, 2): on a segment."""
        out = np.zeros(n, dtype=bool)
        out[self.index[:, which]] = True
        return out


def motion_bound(step: int, max_speed: float, tolerance: float) -> float:
    """l1 = l2 = max_speed x step + tolerance (px, Chebyshev) between combined frames."""
    return max_speed * step + tolerance



def correlate(points1, points2, points3, step: int, evidence: Evidence | None = None,
              gap: int | None = None, *, max_speed: float = 2.0, tolerance: float = 5.0,
              constant_velocity: bool = True, max_deviation: float = 20.0,
              resolve: str = "cost", min_score: float = 3.5,
              verify: float = 6.5, verify_local: float = 3.5,
              screen: float = 0.4, chains_per_point: int = 0) -> Correlation:
    """Find 3-point segments through the fused points of 3 consecutive combined frames.

    Parameters
    ----------
    points1, points2, points3 : structured ndarray with fields ``x``, ``y`` (and
        optionally ``score``), or ndarray of shape (N, 2) of (x, y)
        Fused points (x = column, y = row, px) of combined frames k, k+1, k+2.
    step : int
        Frames between the starts of consecutive combined frames (the time t between
        them), ``CombineConfig.step``.
    gap : int, optional
        Beyond the paper: frames between the starts of combined frames k+1 and k+2 when
        they differ from ``step`` (the tail window over a sequence's last frames,
        ``CombineConfig.tail``, follows the window before it by fewer). The motion
        bound l2 is then max_speed x gap + tolerance, constant velocity puts the third
        point at p2 + (p2 - p1) gap / step, and v = (p3 - p1) / (step + gap).
    evidence : Evidence, optional
        The matched residual frames behind the 3 combined frames (the pipeline passes
        them). With it and ``verify`` > 0, every chain is verified by a velocity-matched
        filter over all the frames of the 3 windows (``track_significance``).
    max_speed : float
        Largest target speed in px/frame (>= 0); with ``tolerance`` it gives the
        paper's motion bounds l1 = l2 = max_speed x step + tolerance.
    tolerance : float
        Position uncertainty of a fused point in px (>= 0), added to the motion bound.
    constant_velocity : bool
        Beyond the paper: also require |p1 - 2 p2 + p3| <= ``max_deviation`` (the middle
        point within reach of the midpoint of the outer two: straight, uniform motion;
        with ``gap``, |p3 - p2 - (p2 - p1) gap / step|).
    max_deviation : float
        Largest deviation from constant velocity in px (> 0), Euclidean.
    min_score : float
        Beyond the paper (0 = off): the mean score (CFAR z) of the 3 points must reach
        it. With the verification, a cheap pre-screen (3.5); without it, the earlier
        default's test (5, with ``k`` 3.5 in ``irdetect.detect``).
    verify : float
        Beyond the paper (0 = off): with ``evidence``, keep a chain only when the
        velocity-matched filter along its straight track reaches ``verify`` noise sigmas
        (a track-before-detect test over every frame of the 3 windows) and the track is
        a point (``ring_significance`` under ``RING_RATIO`` of it); "cost" then
        takes chains by decreasing significance and also drops a chain whose verified
        track runs within ``tolerance`` px of an accepted one in all 3 windows (one
        target, two chains). Segments then carry the verified velocity, and
        ``Correlation.positions`` the verified positions.
    verify_local : float
        Beyond the paper (0 = off, the earlier behaviour): with the verification, a
        verified track must also stand ``verify_local`` robust sigmas above the
        parallel tracks around it (``local_significance``): a local CFAR test of the
        track sum, for clutter whose residue is correlated in time.
    screen : float
        Beyond the paper, a speed/recall trade-off of the verification (0 <= screen
        <= 1): chains whose coarse statistic (the first, nearest-pixel search stage of
        ``track_significance``) is under ``screen`` x ``verify`` are not refined and
        fail. 0.4 (0.5 before: it lost daub-data14's first window, whose target's
        coarse value lies between 0.4 and 0.5 ``verify``, its refined one at 24.8). The
        share of chains refined, and the time, grow fast below it
        (docs/results/verification.md, ``scripts/bench_verification.py``).
    chains_per_point : int
        Beyond the paper, a speed/recall trade-off of the verification (0 = every
        chain, the default): only the ``chains_per_point`` cheapest chains of each
        point, in each of its 3 roles, are verified (cost |p1 - 2 p2 + p3| /
        ``max_deviation`` - mean score / 2, as for ``resolve="cost"``); each chain costs
        the verification 1,296 samples or more. At 2 the verified chains drop from
        about 620 to 280 per window triple at 256x256 and the runs of bench_detection
        and bench_unseen take 30-40 % less time, but weak targets are lost: held-out
        wan2008 SNR 2 Pd 0.87 -> 0.84, SNR 1.5 0.42 -> 0.39 (``--quick``), 24 unseen
        scenes 0.93 -> 0.92 (docs/detection.md).
    resolve : {"cost", "unique", "all"}
        What to do when a point lies on several segments. ``all``: keep every segment
        (the literal set-valued eqs. 5-7). ``unique``: the paper's reading that
        correspondence is unique both ways: keep a segment only when its first point
        starts exactly one forward segment and its last point exactly one backward
        segment. ``cost`` (beyond the paper): one-to-one, taking segments greedily by
        increasing cost |p1 - 2 p2 + p3| / max_deviation - (mean point score) / 2, so
        no point serves twice in one role and a strong straight segment wins over a
        weak noise point that happens to lie a little straighter.

    Returns
    -------
    Correlation
        Segments and the row indices of their points.

    Notes
    -----
    Eq. 5: R123(x, y) = g[f(x,y,1) sum_{p1,q1 in [-l1,l1]} sum_{p2,q2 in [-l2,l2]}
    f(x+p1, y+q1, 2) f(x+p1+p2, y+q1+q2, 3)], g(v) = [v > 0] (eq. 7; the print's
    y+q2 in the second factor is a typo for y+q1). Eq. 6 is the same from frame 3.
    We evaluate both on the fused points with KD-trees in the Chebyshev metric (all
    pairs within l1, then all pairs within l2 of the middle points, joined), not on
    binary images with 4 nested sums: the chains found are exactly those with
    R123 = 1 at their first point and R321 = 1 at their last. Velocity (eq. 8):
    v = (p3 - p1) / (2 step) px/frame. The paper's l1, l2 are not given; we derive them
    from a maximum speed.

    Examples
    --------
    >>> import numpy as np
    >>> c = correlate(np.array([[10., 10.]]), np.array([[22., 10.]]),
    ...               np.array([[34., 11.]]), step=12, min_score=0)
    >>> len(c.segments), float(c.segments["vx"][0])
    (1, 1.0)

    With ``evidence`` the first detection can run at a low threshold: chains of noise
    points are many, but their matched-filter significance stays under about 4 while a
    target's is about 9 at SNR 2 (wan2008).
    """
    pts = [_as_points(p, f"points{i + 1}") for i, p in enumerate((points1, points2, points3))]
    if int(step) != step or step < 1:
        raise ValueError(f"step must be an integer >= 1, got {step!r}")
    gap = step if gap is None else gap
    if int(gap) != gap or gap < 1:
        raise ValueError(f"gap must be an integer >= 1, got {gap!r}")
    steps = (int(step), int(gap))
    ratio = steps[1] / steps[0]          # the constant-velocity prediction's, ``_predicted``
    if not np.isfinite(max_speed) or max_speed < 0:
        raise ValueError(f"max_speed must be a number >= 0, got {max_speed!r}")
    if not np.isfinite(tolerance) or tolerance < 0:
        raise ValueError(f"tolerance must be a number >= 0, got {tolerance!r}")
    if not np.isfinite(max_deviation) or max_deviation <= 0:
        raise ValueError(f"max_deviation must be a positive number, got {max_deviation!r}")
    if not np.isfinite(min_score):
        raise ValueError(f"min_score must be a finite number, got {min_score!r}")
    if resolve not in RESOLVE:
        raise ValueError(f"resolve must be one of {RESOLVE}, got {resolve!r}")
    if not np.isfinite(verify) or verify < 0:
        raise ValueError(f"verify must be a number >= 0, got {verify!r}")
    if not np.isfinite(verify_local) or verify_local < 0:
        raise ValueError(f"verify_local must be a number >= 0, got {verify_local!r}")
    if not np.isfinite(screen) or not 0 <= screen <= 1:
        raise ValueError(f"screen must be a number in [0, 1], got {screen!r}")
    if int(chains_per_point) != chains_per_point or chains_per_point < 0:
        raise ValueError(f"chains_per_point must be an integer >= 0, got {chains_per_point!r}")
    if evidence is not None and not isinstance(evidence, Evidence):
        raise ValueError(f"evidence must be an Evidence, got {type(evidence).__name__}")
    scores = [_scores(p) for p in (points1, points2, points3)]
    bounds = tuple(motion_bound(n, float(max_speed), float(tolerance)) for n in steps)
    index = _chains(pts, bounds, float(max_deviation) if constant_velocity else None, ratio)
    p1, p2, p3 = (pts[i][index[:, i]] for i in range(3))
    deviation = np.hypot(*(p3 - _predicted(p1, p2, ratio)).T) if len(index) else np.zeros(0)
    if constant_velocity:
        keep = deviation <= max_deviation
        index, deviation = index[keep], deviation[keep]
    mean_score = sum(scores[i][index[:, i]] for i in range(3)) / 3.0
    if min_score > 0:
        keep = mean_score >= min_score
        index, deviation, mean_score = index[keep], deviation[keep], mean_score[keep]
    cost = deviation / max_deviation - mean_score / SCORE_SCALE
    if evidence is not None and verify > 0:
        if chains_per_point > 0:
            index = index[_best_per_point(index, cost, int(chains_per_point))]
        return _verified(pts, scores, index, steps, evidence, float(verify), resolve,
                         float(tolerance), float(verify_local), float(screen))
    if resolve == "unique":
        index, deviation = _unique(index, deviation)
    elif resolve == "cost":
        index, deviation = _greedy(index, cost)
    return Correlation(segments=_segments(pts, scores, index, steps), index=index,
                       positions=np.full((len(index), 3, 2), np.nan),
                       significance=np.full(len(index), np.nan))


def _best_per_point(index, cost, k) -> np.ndarray:
    """Rows (sorted) of the chains (``index`` (n, 3)) among the ``k`` cheapest (``cost``
    (n,)) of their first, middle or last point."""
    keep = np.zeros(len(index), bool)
    for i in range(3):
        order = np.lexsort((cost, index[:, i]))
        key = index[order, i]
        start = np.searchsorted(key, key, side="left")
        rank = np.arange(len(key)) - start
        keep[order[rank < k]] = True
    return np.flatnonzero(keep)


def _verified(pts, scores, index, steps, evidence, verify, resolve, tolerance,
              verify_local, screen) -> Correlation:
    points = (np.stack([pts[i][index[:, i]] for i in range(3)], axis=1) if len(index)
              else np.zeros((0, 3, 2)))
    keep, z, c, v = verify_tracks(evidence, points, verify=verify,
                                  verify_local=verify_local, screen=screen)
    index = index[keep]
    tm = float(np.mean(evidence.index))
    report = np.asarray(evidence.report, np.float64) - tm
    positions = c[:, None, :] + v[:, None, :] * report[None, :, None]      # (n, 3, 2)
    if resolve == "cost":
        sel = _greedy_tracks(index, -z, positions, tolerance)
    elif resolve == "unique":
        sel = _unique_rows(index)
    else:
        sel = np.arange(len(index))
    index, z, positions, v = index[sel], z[sel], positions[sel], v[sel]
    segments = _segments(pts, scores, index, steps)
    segments["vx"], segments["vy"] = v[:, 0], v[:, 1]
    return Correlation(segments=segments, index=index, positions=positions, significance=z)


def _unique_rows(index) -> np.ndarray:
    if len(index) == 0:
        return np.zeros(0, np.int64)
    fwd = np.bincount(index[:, 0])[index[:, 0]]
    bwd = np.bincount(index[:, 2])[index[:, 2]]
    return np.flatnonzero((fwd == 1) & (bwd == 1))


def _greedy_tracks(index, cost, positions, tolerance) -> np.ndarray:
    """Rows taken greedily by increasing cost: one-to-one in points, and no two tracks
    within ``tolerance`` px of each other in all 3 windows (a loop over the chains that
    passed verification: a handful per frame)."""
    used = [set(), set(), set()]
    keep: list[int] = []
    for s in np.argsort(cost, kind="stable"):
        i1, i2, i3 = index[s]
        if i1 in used[0] or i2 in used[1] or i3 in used[2]:
            continue
        if keep and (np.hypot(*(positions[keep] - positions[s]).transpose(2, 0, 1))
                     <= tolerance).all(axis=1).any():
            continue
        used[0].add(i1), used[1].add(i2), used[2].add(i3)
        keep.append(s)
    return np.sort(np.array(keep, dtype=np.int64))


def _as_points(p, name) -> np.ndarray:
    a = np.asarray(p)
    if a.dtype.names is not None:
        if "x" not in a.dtype.names or "y" not in a.dtype.names:
            raise ValueError(f"{name} must have fields x and y, got {a.dtype.names}")
        out = np.column_stack([a["x"], a["y"]]).astype(np.float64)
    else:
        if a.size == 0:
            return np.zeros((0, 2))
        if a.ndim != 2 or a.shape[1] != 2:
            raise ValueError(f"{name} must have shape (N, 2), got {a.shape}")
        out = a.astype(np.float64)
    if not np.isfinite(out).all():
        raise ValueError(f"{name} must be finite")
    return out.reshape(-1, 2)


def _scores(p) -> np.ndarray:
    a = np.asarray(p)
    if a.dtype.names is not None and "score" in a.dtype.names:
        return a["score"].astype(np.float64)
    return np.zeros(len(a))


def _pairs(a: np.ndarray, b: np.ndarray, bound: float) -> np.ndarray:
    if len(a) == 0 or len(b) == 0:
        return np.zeros((0, 2), np.int64)
    m = cKDTree(a).sparse_distance_matrix(cKDTree(b), bound, p=np.inf, output_type="ndarray")
    return np.column_stack([m["i"], m["j"]]).astype(np.int64)


def _predicted(p1, p2, ratio: float) -> np.ndarray:
    """Where constant velocity puts the third point: p2 + (p2 - p1) ``ratio``, ``ratio``
    the frames between the second and third windows over those between the first two
    (2 p2 - p1 for equally spaced windows)."""
    return p2 + (p2 - p1) * ratio


def _chains(pts, bounds, deviation: float | None = None, ratio: float = 1.0) -> np.ndarray:
    """All (i1, i2, i3) with |p2 - p1|_inf <= bounds[0] and |p3 - p2|_inf <= bounds[1],
    ordered by the row of (i1, i2) among the frame 1 -> 2 pairs, then of (i2, i3) among
    the frame 2 -> 3 pairs (by i2, stable).

    ``deviation``: only (a superset, by 1e-9 relative, of) the chains whose third point
    lies within ``deviation`` of ``_predicted`` (|p1 - 2 p2 + p3| for equally spaced
    windows), in the same order: frame 3's points are looked up around each pair's
    prediction instead of joining all pairs (a fast band's motion bound of 77 px joins
    ~10,000 chains of which a few hundred are straight).
    """
    a = _pairs(pts[0], pts[1], bounds[0])      # forward: frame 1 -> frame 2
    b = _pairs(pts[1], pts[2], bounds[1])      # frame 2 -> frame 3
    if len(a) == 0 or len(b) == 0:
        return np.zeros((0, 3), np.int64)
    b = b[np.argsort(b[:, 0], kind="stable")]
    if deviation is not None:
        return _straight_chains(pts, a, b, bounds[1], deviation, ratio)
    lo = np.searchsorted(b[:, 0], a[:, 1], side="left")
    hi = np.searchsorted(b[:, 0], a[:, 1], side="right")
    n = hi - lo
    rep = np.repeat(np.arange(len(a)), n)
    offs = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    j = lo[rep] + offs
    return np.column_stack([a[rep, 0], a[rep, 1], b[j, 1]]).astype(np.int64)


def _straight_chains(pts, a, b, bound, deviation, ratio) -> np.ndarray:
    """``_chains`` with ``deviation`` from the pairs ``a`` (frame 1 -> 2) and ``b`` (frame
    2 -> 3 within ``bound``, sorted by i2, stable)."""
    pred = _predicted(pts[0][a[:, 0]], pts[1][a[:, 1]], ratio)
    m = cKDTree(pred).sparse_distance_matrix(cKDTree(pts[2]), deviation * (1 + 1e-9) + 1e-12,
                                             p=2, output_type="ndarray")
    ia, i3 = m["i"].astype(np.int64), m["j"].astype(np.int64)
    i2 = a[ia, 1]
    near = np.abs(pts[2][i3] - pts[1][i2]).max(axis=1) <= bound
    ia, i2, i3 = ia[near], i2[near], i3[near]
    # the row of each (i2, i3) in b: the order of the full join
    n3 = len(pts[2])
    key = b[:, 0] * n3 + b[:, 1]
    by_key = np.argsort(key, kind="stable")
    row = by_key[np.searchsorted(key[by_key], i2 * n3 + i3)]
    order = np.lexsort((row, ia))
    return np.column_stack([a[ia, 0], i2, i3])[order].astype(np.int64)


def _unique(index, deviation):
    if len(index) == 0:
        return index, deviation
    fwd = np.bincount(index[:, 0])[index[:, 0]]   # segments starting at this frame-1 point
    bwd = np.bincount(index[:, 2])[index[:, 2]]   # segments ending at this frame-3 point
    keep = (fwd == 1) & (bwd == 1)
    return index[keep], deviation[keep]


def _greedy(index, deviation):
    if len(index) <= 1:
        return index, deviation
    order = np.argsort(deviation, kind="stable")
    used = [set(), set(), set()]
    keep = []
    for s in order:          # a loop over candidate segments (a handful per frame)
        i1, i2, i3 = index[s]
        if i1 in used[0] or i2 in used[1] or i3 in used[2]:
            continue
        used[0].add(i1), used[1].add(i2), used[2].add(i3)
        keep.append(s)
    keep = np.sort(np.array(keep, dtype=np.int64))
    return index[keep], deviation[keep]


def _segments(pts, scores, index, steps) -> np.ndarray:
    """SEGMENT rows of the chains ``index``, v = (p3 - p1) / (frames from window 1 to 3)."""
    if len(index) == 0:
        return empty(SEGMENT)
    out = np.zeros(len(index), dtype=SEGMENT)
    for i, (xf, yf) in enumerate((("x1", "y1"), ("x2", "y2"), ("x3", "y3"))):
        out[xf] = pts[i][index[:, i], 0]
        out[yf] = pts[i][index[:, i], 1]
    out["vx"] = (out["x3"] - out["x1"]) / sum(steps)
    out["vy"] = (out["y3"] - out["y1"]) / sum(steps)
    out["score"] = sum(scores[i][index[:, i]] for i in range(3)) / 3.0
    return out
