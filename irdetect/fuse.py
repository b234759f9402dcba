"""Groups and probability-weighted fusion (Wan & Askar 2008, section 3.2).

Candidate pixels that lie close together form a group, one group per target; each group
is fused into one point with weights inversely proportional to the members' distances
from the group centroid.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.spatial import cKDTree

from irdetect.detect import DirectionalDetection
from irdetect.tables import CANDIDATE, empty


def fuse(detection: DirectionalDetection, combined, *, gap: int = 1, d_min: float = 0.5,
         min_members: int = 1, peak_radius: int = 5, extent: float = 0.0) -> np.ndarray:
    """Group candidate pixels and fuse each group into one point.

    Parameters
    ----------
    detection : DirectionalDetection
        Output of ``irdetect.detect.detect`` for the combined frame.
    combined : ndarray of shape (H, W)
        The combined frame the detection ran on (the fused intensity is taken from it).
    gap : int
        Two candidate pixels belong to the same group when they are linked through
        candidate pixels at most ``gap + 1`` px apart (Chebyshev distance): ``gap = 0`` is
        plain 8-connectivity, ``gap = 1`` also bridges a one-pixel hole in a streak.
    d_min : float
        Distance floor in px for the weights (> 0): a member on, or nearer than
        ``d_min`` to, the centroid gets the largest weight 1/d_min instead of a
        division by zero.
    min_members : int
        Groups with fewer member pixels are dropped (1 keeps every group).
    peak_radius : int
        Beyond the paper (0 = off): split a group around its local maxima of the CFAR
        response that are at least ``peak_radius`` px apart (each pixel goes to the
        nearest maximum), so two targets passing close by stay two points.
    extent : float
        Beyond the paper (0 = off; needs ``peak_radius`` > 0): only the pixels within
        ``extent`` px of their group's maximum are its members, so a target inside a wide
        region above the threshold (a bright target's bloom in the fast band's merit, a
        clutter edge it sits on) is fused near its peak, not at the region's centroid.

    Returns
    -------
    ndarray of dtype ``irdetect.tables.CANDIDATE``
        One row per group: ``x``, ``y`` (px; x = column, y = row) the fused position,
        ``intensity`` the fused combined-frame value, ``score`` the group's largest CFAR
        response, ``n_members`` its pixel count, ``direction`` the winning direction of
        its strongest pixel; ``frame_start``, ``frame_end``, ``combined_frame`` are 0 and
        ``confirmed`` False (the pipeline fills them). Sorted by decreasing score.

    Notes
    -----
    Paper, eq. 3 (garbled in the text; this is its evident meaning) and eq. 4: with c the
    centroid of the group's member positions p_i and d_i = |p_i - c|,

        beta_i = (1 / d_i) / sum_j (1 / d_j),   M = sum_i beta_i p_i,
        I = sum_i beta_i C(p_i).

    We use max(d_i, d_min) for d_i so that the case d_i = 0 is defined; the paper does not
    handle it. A single-pixel group fuses to that pixel.

    Examples
    --------
    >>> import numpy as np
    >>> from irdetect.detect import DirectionalDetection
    >>> mask = np.zeros((9, 9), bool); mask[3:6, 3:6] = True
    >>> det = DirectionalDetection(mask, np.where(mask, 0, -1).astype(np.int8),
    ...                            mask.astype(np.float32) * 5)
    >>> row = fuse(det, mask.astype(np.float32))[0]
    >>> float(row["x"]), float(row["y"]), int(row["n_members"])
    (4.0, 4.0, 9)
    """
    if not isinstance(detection, DirectionalDetection):
        raise ValueError(f"detection must be a DirectionalDetection, got {type(detection).__name__}")
    values = np.asarray(combined)
    if values.shape != detection.mask.shape:
        raise ValueError(f"combined must have the detection's shape {detection.mask.shape}, "
                         f"got {values.shape}")
    if int(gap) != gap or gap < 0:
        raise ValueError(f"gap must be an integer >= 0, got {gap!r}")
    if not np.isfinite(d_min) or d_min <= 0:
        raise ValueError(f"d_min must be a positive number, got {d_min!r}")
    if int(min_members) != min_members or min_members < 1:
        raise ValueError(f"min_members must be an integer >= 1, got {min_members!r}")
    if int(peak_radius) != peak_radius or peak_radius < 0:
        raise ValueError(f"peak_radius must be an integer >= 0, got {peak_radius!r}")
    if not np.isfinite(extent) or extent < 0:
        raise ValueError(f"extent must be a number >= 0, got {extent!r}")
    return _fuse(detection, values, int(gap), float(d_min), int(min_members), int(peak_radius),
                 float(extent))


def group_labels(mask: np.ndarray, gap: int) -> tuple[int, np.ndarray]:
    """Label the groups of a candidate mask: (n_groups, labels of shape (H, W), 0 = none)."""
    n, labels = _components(mask, gap)
    return n, np.where(mask, labels, 0)


def _components(mask: np.ndarray, gap: int) -> tuple[int, np.ndarray]:
    """Groups as labelled components of the dilated mask (labels off the mask not zeroed)."""
    m = np.ascontiguousarray(mask).view(np.uint8) if mask.dtype == bool else mask.astype(np.uint8)
    if gap > 0:
        # p and q join when (p + B) and (q + B) touch, B a (gap + 1)-square: |p - q| <= gap + 1
        kern = np.ones((gap + 1, gap + 1), np.uint8)
        m = cv2.dilate(m, kern, anchor=(0, 0), borderType=cv2.BORDER_CONSTANT, borderValue=0)
    n, labels = cv2.connectedComponents(m, connectivity=8, ltype=cv2.CV_32S)
    return n - 1, labels


#: a local maximum splits its group only when its response reaches this fraction of the
#: group's largest (weaker bumps on a bright blob's flank are not a second target)
PEAK_RATIO = 0.5


def _peak_labels(det: DirectionalDetection, idx, lab, radius: int):
    """Label of the nearest strong local maximum (plateaus merged) for each candidate
    pixel, and the pixel's distance to it in px.

    ``idx`` are the candidates' flat (row-major) pixel indices, ``lab`` their group labels.
    """
    h, w = det.mask.shape
    r = det.response.reshape(-1)[idx]
    resp = np.full(h * w, -np.inf, np.float32)
    resp[idx] = r
    kern = np.ones((2 * radius + 1, 2 * radius + 1), np.uint8)
    is_peak = r >= cv2.dilate(resp.reshape(h, w), kern).reshape(-1)[idx]
    pidx = idx[is_peak]
    img = np.zeros(h * w, np.uint8)
    img[pidx] = 1
    n, plab = cv2.connectedComponents(img.reshape(h, w), connectivity=8)
    py, px = np.divmod(pidx, w)
    pl = plab.reshape(-1)[pidx] - 1
    cnt = np.bincount(pl, minlength=n - 1)
    centres = np.column_stack([np.bincount(pl, px, n - 1) / cnt, np.bincount(pl, py, n - 1) / cnt])
    # each peak's response and its group's largest response
    peak_resp = np.full(n - 1, -np.inf)
    np.maximum.at(peak_resp, pl, r[is_peak])
    group = np.zeros(n - 1, np.int64)
    group[pl] = lab[is_peak]
    group_max = np.full(int(lab.max()) + 1, -np.inf)
    np.maximum.at(group_max, group, peak_resp)
    strong = peak_resp >= PEAK_RATIO * group_max[group]
    ys, xs = np.divmod(idx, w)
    dist, near = cKDTree(centres[strong]).query(np.column_stack([xs, ys]))
    return np.flatnonzero(strong)[near], dist


def _fuse(det: DirectionalDetection, values: np.ndarray, gap: int, d_min: float,
          min_members: int, peak_radius: int = 0, extent: float = 0.0) -> np.ndarray:
    # flat indices of the candidates, row-major (the order of np.nonzero)
    idx = np.flatnonzero(det.mask)
    if idx.size == 0:
        return empty(CANDIDATE)
    ys, xs = np.divmod(idx, det.mask.shape[1])
    _, labels = _components(det.mask, gap)
    lab = labels.reshape(-1)[idx]
    if peak_radius > 0:
        # a pixel's group is (its connected group, its nearest response maximum)
        peak, dist = _peak_labels(det, idx, lab, peak_radius)
        lab = lab.astype(np.int64) * (int(peak.max()) + 1) + peak
        if extent > 0:
            near = dist <= extent
            idx, ys, xs, lab = idx[near], ys[near], xs[near], lab[near]
    # compact labels (dilation may create label ids without members)
    uniq, lab = np.unique(lab, return_inverse=True)
    g = len(uniq)
    xs = xs.astype(np.float64)
    ys = ys.astype(np.float64)
    count = np.bincount(lab, minlength=g).astype(np.float64)
    cx = np.bincount(lab, xs, g) / count
    cy = np.bincount(lab, ys, g) / count
    d = np.hypot(xs - cx[lab], ys - cy[lab])
    w = 1.0 / np.maximum(d, d_min)
    wsum = np.bincount(lab, w, g)
    beta = w / wsum[lab]
    fx = np.bincount(lab, beta * xs, g)
    fy = np.bincount(lab, beta * ys, g)
    val = values.reshape(-1)[idx].astype(np.float64)
    inten = np.bincount(lab, beta * val, g)
    resp = det.response.reshape(-1)[idx].astype(np.float64)
    # strongest member per group: sort by (label, response) and take each label's last
    order = np.lexsort((resp, lab))
    last = order[np.r_[np.flatnonzero(np.diff(lab[order])), len(order) - 1]]
    score = resp[last]
    direction = det.direction.reshape(-1)[idx][last]
    keep = count >= min_members
    out = np.zeros(int(keep.sum()), dtype=CANDIDATE)
    out["x"], out["y"] = fx[keep], fy[keep]
    out["intensity"], out["score"] = inten[keep], score[keep]
    out["n_members"], out["direction"] = count[keep], direction[keep]
    return out[np.argsort(-out["score"], kind="stable")]
