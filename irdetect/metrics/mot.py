"""CLEAR-MOT (MOTA, MOTP) and identity (IDF1) scores of a multi-target tracker.

References: Bernardin & Stiefelhagen, "Evaluating multiple object tracking performance: the
CLEAR MOT metrics", EURASIP JIVP 2008; Ristani et al., "Performance measures and a data set
for multi-target, multi-camera tracking", ECCV workshops 2016. Hand-written; the tests compare
it with hand-computed cases (and with py-motmetrics when that optional package is installed).
"""

from __future__ import annotations

from collections import defaultdict

import numpy as np
from scipy.optimize import linear_sum_assignment

_BIG = 1e12


def clear_mot(truth: np.ndarray, hypotheses: np.ndarray, *, gate: float) -> dict:
    """Score tracker output against ground truth.

    Parameters
    ----------
    truth : structured ndarray with fields frame, target, x, y
        Ground truth (``irdetect.tables.TRUTH``); x = column, y = row, pixels.
    hypotheses : structured ndarray with fields frame, track_id, x, y
        Tracker output (``irdetect.tables.TRACK_POINT``).
    gate : float
        A hypothesis matches a truth point only within this Euclidean distance (pixels).

    Returns
    -------
    dict
        ``mota`` = 1 - (FN + FP + IDSW) / GT, ``motp`` = mean distance of the matches in
        pixels (NaN without matches), ``idf1`` = 2 IDTP / (GT + HYP), ``idp``, ``idr``,
        ``id_switches``, ``fn`` (misses), ``fp`` (false positives), ``matches``,
        ``n_truth`` (GT), ``n_hyp`` (HYP), ``n_targets``, ``n_tracks``.

    Notes
    -----
    Per frame, a correspondence of the previous frames (truth -> hypothesis) is kept when
    both are present and still within the gate; the remaining pairs are matched by minimum
    total distance (Hungarian) inside the gate. An id switch is counted when a truth object
    is matched to a hypothesis other than the one it was last matched to (gaps in between
    allowed), as in CLEAR-MOT and py-motmetrics. IDF1 uses the one-to-one truth/track
    assignment that maximises the number of frames in which the pair is within the gate.
    A hypothesis id may be reused by a truth object after a gap; an empty truth gives
    mota = NaN.
    """
    if not gate > 0:
        raise ValueError(f"gate must be > 0, got {gate!r}")
    for name, table, fields in (("truth", truth, ("frame", "target", "x", "y")),
                                ("hypotheses", hypotheses, ("frame", "track_id", "x", "y"))):
        missing = [f for f in fields if table.dtype.names is None or f not in table.dtype.names]
        if missing:
            raise ValueError(f"{name} lacks fields {missing}")
    return _score(truth, hypotheses, float(gate))


def _by_frame(frames: np.ndarray) -> dict:
    order = np.argsort(frames, kind="stable")
    f = frames[order]
    cuts = np.flatnonzero(np.diff(f)) + 1
    return {int(g[0]): idx for g, idx in zip(np.split(f, cuts), np.split(order, cuts)) if len(g)}


def _score(truth, hyp, gate):
    gt_f, hy_f = _by_frame(truth["frame"]), _by_frame(hyp["frame"])
    last: dict[int, int] = {}
    fn = fp = idsw = matches = 0
    dist_sum = 0.0
    pair_hits: dict[tuple[int, int], int] = defaultdict(int)
    for frame in sorted(set(gt_f) | set(hy_f)):
        gi = gt_f.get(frame, np.zeros(0, int))
        hi = hy_f.get(frame, np.zeros(0, int))
        gids, hids = truth["target"][gi].astype(int), hyp["track_id"][hi].astype(int)
        gxy = np.column_stack([truth["x"][gi], truth["y"][gi]])
        hxy = np.column_stack([hyp["x"][hi], hyp["y"][hi]])
        d = np.linalg.norm(gxy[:, None, :] - hxy[None, :, :], axis=2) if len(gi) and len(hi) \
            else np.zeros((len(gi), len(hi)))
        within = d <= gate
        for a, b in zip(*np.nonzero(within)):
            pair_hits[(int(gids[a]), int(hids[b]))] += 1
        pairs = []
        used_g, used_h = np.zeros(len(gi), bool), np.zeros(len(hi), bool)
        hpos = {h: k for k, h in enumerate(hids)}
        for a, g in enumerate(gids):                       # keep last correspondences
            b = hpos.get(last.get(int(g), -10 ** 18))
            if b is not None and within[a, b] and not used_h[b]:
                pairs.append((a, b))
                used_g[a] = used_h[b] = True
        ra, rb = np.flatnonzero(~used_g), np.flatnonzero(~used_h)
        if len(ra) and len(rb):
            sub = d[np.ix_(ra, rb)]
            cost = np.where(sub <= gate, sub, _BIG)
            rows, cols = linear_sum_assignment(cost)
            for r_, c_ in zip(rows, cols):
                if cost[r_, c_] < _BIG:
                    a, b = ra[r_], rb[c_]
                    g, h = int(gids[a]), int(hids[b])
                    if g in last and last[g] != h:
                        idsw += 1
                    pairs.append((a, b))
        for a, b in pairs:
            last[int(gids[a])] = int(hids[b])
            dist_sum += d[a, b]
        matches += len(pairs)
        fn += len(gi) - len(pairs)
        fp += len(hi) - len(pairs)
    n_truth, n_hyp = len(truth), len(hyp)
    tids, hids_all = np.unique(truth["target"]), np.unique(hyp["track_id"])
    idtp = 0
    if len(tids) and len(hids_all) and pair_hits:
        tpos = {int(t): k for k, t in enumerate(tids)}
        hpos_all = {int(h): k for k, h in enumerate(hids_all)}
        m = np.zeros((len(tids), len(hids_all)))
        for (g, h), c in pair_hits.items():
            m[tpos[g], hpos_all[h]] = c
        rows, cols = linear_sum_assignment(-m)
        idtp = int(m[rows, cols].sum())
    nan = float("nan")
    return {
        "mota": 1 - (fn + fp + idsw) / n_truth if n_truth else nan,
        "motp": dist_sum / matches if matches else nan,
        "idf1": 2 * idtp / (n_truth + n_hyp) if n_truth + n_hyp else nan,
        "idp": idtp / n_hyp if n_hyp else nan,
        "idr": idtp / n_truth if n_truth else nan,
        "id_switches": idsw, "fn": fn, "fp": fp, "matches": matches,
        "n_truth": n_truth, "n_hyp": n_hyp, "n_targets": len(tids), "n_tracks": len(hids_all),
    }
