"""Detection scores against ground truth: Pd, false detections, pixel-level Fa.

A detection is made per combined frame (a window of frames). A target present in a window
is *detected* when a confirmed detection of that window lies within ``gate`` px of the
target's true path over the window (the polyline through its true positions in the
window's frames), matched one-to-one (Hungarian assignment on the distances, pairs beyond
the gate forbidden). Every unmatched detection is a false detection.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from irdetect.combine import window_starts

_FAR = 1e9
#: the benchmarks' presence rule (``score_detections``'s ``presence``): a target counts
#: in a window when it is inside the frame in three quarters of its frames
PRESENCE = 0.75


def path_distance(points: np.ndarray, path: np.ndarray) -> np.ndarray:
    """Distance of each point to a polyline.

    Parameters
    ----------
    points : ndarray of shape (N, 2)
        (x, y) px.
    path : ndarray of shape (M, 2)
        Polyline vertices (x, y) in order (M >= 1; M = 1 is a single point).

    Returns
    -------
    ndarray of shape (N,)
    """
    p = np.asarray(points, float).reshape(-1, 2)
    v = np.asarray(path, float).reshape(-1, 2)
    if len(v) == 1:
        return np.hypot(*(p - v[0]).T)
    a, b = v[:-1], v[1:]                       # (S, 2)
    ab = b - a
    len2 = np.maximum((ab ** 2).sum(1), 1e-12)
    t = ((p[:, None, :] - a[None]) * ab[None]).sum(2) / len2
    t = np.clip(t, 0.0, 1.0)
    closest = a[None] + t[..., None] * ab[None]
    return np.hypot(*(p[:, None, :] - closest).transpose(2, 0, 1)).min(axis=1)


def score_detections(detections: np.ndarray, truth: np.ndarray, *, n_frames: int,
                     length: int, step: int, shape: tuple[int, int],
                     gate: float = 3.0, footprint: int = 3, tail: bool = False,
                     presence: float = 0.0) -> dict:
    """Pd, false detections and pixel-level Fa of confirmed detections.

    Parameters
    ----------
    detections : structured ndarray with fields ``x``, ``y``, ``combined_frame``
        ``irdetect.tables.DETECTION`` rows (x = column, y = row, px).
    truth : structured ndarray with fields ``frame``, ``target``, ``x``, ``y``
        ``irdetect.tables.TRUTH`` rows.
    n_frames, length, step : int
        The sequence length and the combined-frame windows (``CombineConfig``); window k
        covers frames [k step, k step + length).
    shape : (int, int)
        Frame (H, W), for the per-megapixel rate and the pixel-level Fa.
    gate : float
        Match distance in px (> 0) between a detection and a target's path in the window.
    footprint : int
        Odd side in px of the square each detection is rasterised to for the pixel Fa.
    tail : bool
        The run had the tail window (``CombineConfig.tail``): when the windows leave
        frames after them, the last window covers [n_frames - length, n_frames)
        (``irdetect.combine.window_starts``). Without it, detections of that window are
        not scored.
    presence : float
        The presence rule, in [0, 1]: a target counts in a window only when it is inside
        the frame (0 <= x <= W - 1, 0 <= y <= H - 1) in at least this share of the
        window's ``length`` frames; a detection within ``gate`` of the path of a target
        inside for less, and of no counted target, is set aside: neither detected nor
        false (a target entering or leaving the view; ``irdetect process`` reports a
        detection at its window's middle frame, inside the image). 0: every target in
        the truth counts.

    Returns
    -------
    dict
        ``windows``, ``targets`` (target-windows counted), ``detected``, ``pd``,
        ``detections``, ``false``, ``false_per_window``, ``false_per_mpx_window``,
        ``pixel_fa``, ``mean_error_px`` (distance of matched detections to the path),
        ``set_aside`` (detections of targets present for less than ``presence``).

    Notes
    -----
    Pixel-level Fa follows the IRSTD convention (Fa = false-alarm pixels / all pixels):
    a point detection has no extent, so each detection is rasterised to the
    ``footprint`` x ``footprint`` px square centred on its rounded position (the 3x3 px
    target of the paper), clipped to the frame; the false-alarm pixels of a window are
    the union of the squares of its unmatched detections; Fa sums them over windows and
    divides by windows x H x W.
    """
    if gate <= 0 or not np.isfinite(gate):
        raise ValueError(f"gate must be a positive number, got {gate!r}")
    if int(footprint) != footprint or footprint < 1 or footprint % 2 == 0:
        raise ValueError(f"footprint must be an odd integer >= 1, got {footprint!r}")
    if not 0 <= presence <= 1:
        raise ValueError(f"presence must lie in [0, 1], got {presence!r}")
    h, w = int(shape[0]), int(shape[1])
    starts = window_starts(int(n_frames), length=length, step=step, tail=tail)
    det = np.asarray(detections)
    tru = np.asarray(truth)
    targets = detected = false = false_px = set_aside = 0
    errors = []
    half = footprint // 2
    for k, s in enumerate(starts):
        dk = det[det["combined_frame"] == k]
        pts = np.column_stack([dk["x"], dk["y"]]).astype(float)
        tk = tru[(tru["frame"] >= s) & (tru["frame"] < s + length)]
        ids = np.unique(tk["target"])
        cost = _path_distances(pts, tk, ids)
        if presence > 0:
            inside = (tk["x"] >= 0) & (tk["x"] <= w - 1) & (tk["y"] >= 0) & (tk["y"] <= h - 1)
            shown = np.bincount(np.searchsorted(ids, tk["target"][inside]),
                                minlength=len(ids))
            counted = shown >= presence * length
            aside = ((cost[~counted] <= gate).any(axis=0)
                     & ~(cost[counted] <= gate).any(axis=0))
            set_aside += int(aside.sum())
            dk, pts, cost, ids = dk[~aside], pts[~aside], cost[counted][:, ~aside], ids[counted]
        targets += len(ids)
        matched = np.zeros(len(dk), bool)
        if len(ids) and len(dk):
            gated = np.where(cost <= gate, cost, _FAR)
            rows, cols = linear_sum_assignment(gated)
            ok = gated[rows, cols] < _FAR
            detected += int(ok.sum())
            matched[cols[ok]] = True
            errors.extend(cost[rows[ok], cols[ok]].tolist())
        nf = int((~matched).sum())
        false += nf
        if nf:
            mask = np.zeros((h, w), bool)
            for x, y in pts[~matched]:
                cx, cy = int(round(x)), int(round(y))
                mask[max(0, cy - half):max(0, cy + half + 1),
                     max(0, cx - half):max(0, cx + half + 1)] = True
            false_px += int(mask.sum())
    n_win = len(starts)
    mpx = h * w / 1e6
    return {
        "windows": n_win,
        "targets": targets,
        "detected": detected,
        "pd": detected / targets if targets else float("nan"),
        "detections": int(len(det)),
        "false": false,
        "false_per_window": false / n_win if n_win else float("nan"),
        "false_per_mpx_window": false / (n_win * mpx) if n_win else float("nan"),
        "pixel_fa": false_px / (n_win * h * w) if n_win else float("nan"),
        "mean_error_px": float(np.mean(errors)) if errors else float("nan"),
        "gate": float(gate),
        "set_aside": set_aside,
    }


def _path_distances(points: np.ndarray, truth: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """(len(ids), len(points)): each point's distance to the path of each target of
    ``ids`` through its ``truth`` rows in time order (``path_distance``)."""
    cost = np.empty((len(ids), len(points)))
    for i, j in enumerate(ids):           # a loop over the few targets
        tj = truth[truth["target"] == j]
        tj = tj[np.argsort(tj["frame"])]
        cost[i] = path_distance(points, np.column_stack([tj["x"], tj["y"]]))
    return cost


#: the false-detection rate per frame up to which ``roc`` integrates its area (the
#: real-data goal: 0.1 false detections per frame, 1.2 per 12-frame window)
ROC_FALSE_MAX = 0.1
#: the most thresholds ``roc`` sweeps (quantiles of the scores)
ROC_POINTS = 40


def roc(detections: np.ndarray, truth: np.ndarray, *, n_frames: int, length: int, step: int,
        shape: tuple[int, int], gate: float = 3.0, score: str = "snr",
        false_max: float = ROC_FALSE_MAX, tail: bool = False,
        presence: float = 0.0) -> dict:
    """Pd and false detections per frame of the detections at or above a sweep of scores.

    Parameters
    ----------
    detections, truth, n_frames, length, step, shape, gate, tail, presence
        As ``score_detections``.
    score : str
        The field ranked (``snr``: the local SNR both paths share; ``score``).
    false_max : float
        The area is taken over false detections per frame in [0, ``false_max``].

    Returns
    -------
    dict
        ``thresholds``, ``pd``, ``false_per_frame`` (lists, thresholds decreasing, the
        last one every detection); ``auc``: the area under Pd against false detections per
        frame from 0 to ``false_max`` (Pd at rate F being the best Pd of a threshold with
        at most F false per frame), divided by ``false_max``: 1 when every target is
        found with no false detection, the share of target-windows found at zero false
        alarms when none can be found without them. NaN without targets.
    """
    det = np.asarray(detections)
    s = np.nan_to_num(det[score].astype(float), nan=-np.inf) if len(det) else np.zeros(0)
    finite = np.unique(s[np.isfinite(s)])
    if len(finite) > ROC_POINTS:
        finite = np.unique(np.quantile(finite, np.linspace(0.0, 1.0, ROC_POINTS)))
    # every detection at the last threshold (-inf only when some score is not finite)
    thresholds = np.r_[np.inf, finite[::-1], [-np.inf] if len(finite) < len(np.unique(s))
                       or not len(finite) else []]
    pd, fpf = [], []
    for t in thresholds:                  # a loop over a few dozen thresholds
        m = score_detections(det[s >= t], truth, n_frames=n_frames, length=length, step=step,
                             shape=shape, gate=gate, tail=tail, presence=presence)
        pd.append(m["pd"])
        fpf.append(m["false"] / n_frames)
    pd, fpf = np.array(pd), np.array(fpf)
    if not np.isfinite(pd).any():
        auc = float("nan")
    else:
        # the best Pd reachable at each rate: a step function over the sorted rates
        grid = np.linspace(0.0, false_max, 201)
        best = np.array([pd[fpf <= f].max() if (fpf <= f).any() else 0.0 for f in grid])
        auc = float(np.trapezoid(best, grid) / false_max)
    return {"thresholds": thresholds[1:].tolist(), "pd": pd[1:].tolist(),
            "false_per_frame": fpf[1:].tolist(), "auc": auc, "score": score}
