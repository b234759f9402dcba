"""Pd and Fa as the infrared small-target detection (IRSTD) field computes them from masks.

IRSTD papers (SIRST, IRSTD-1k, NUDT-SIRST, ...) score a predicted mask against a truth mask
per image, the way ``pyirstdmetrics.ProbabilityDetectionAndFalseAlarmRate`` (1.0.2) does:

- the targets are the 8-connected regions of each mask, in raster order of their first
  pixel; a region's centroid is the mean (x, y) of its pixels;
- in that order, each truth target takes the first predicted region not yet taken whose
  centroid lies closer than ``distance`` px to its own (strictly: ``d < distance``; 3 px
  in the field's code) and is then *detected*;
- Pd = detected targets / truth targets, over all images;
- Fa = the pixels of the predicted regions no target took / all pixels of all images.

irdetect's results are points, so they are first drawn as masks: a detection as its region
(``/track_points`` of ``irdetect track`` carry the region's area: a disc of that area on
the centroid) or, where only its centroid is known (``/detections`` of ``irdetect
process``), a small disc; the truth as a disc on each target's position (the truth tables
hold points). Overlapping discs merge into one region, as touching targets do in a mask.
The images are the combined frames for ``/detections`` (the truth at each window's middle
time, where a detection is reported: docs/detection.md) and the frames for
``/track_points``.

These are not irdetect's own Pd (target-windows matched one to one within the gate of the
true path) and pixel Fa (3x3 px per false detection): docs/format.md says which is which.
"""

from __future__ import annotations

import cv2
import numpy as np

from irdetect.combine import window_starts

#: radius in px of the disc a point is drawn as (a centred point covers 3 x 3 px: the
#: point target of the papers irdetect follows)
POINT_RADIUS = 1.5


def draw_discs(points: np.ndarray, shape: tuple[int, int], radius=POINT_RADIUS) -> np.ndarray:
    """Rasterise discs into a mask.

    Parameters
    ----------
    points : ndarray of shape (N, 2)
        Centres (x, y) = (column, row) in px; pixel (r, c) has its centre at x = c, y = r.
    shape : (int, int)
        Mask (H, W).
    radius : float or ndarray of shape (N,)
        Disc radius in px, one for all or one per point; a pixel belongs to a disc when
        its centre lies within ``radius`` of the disc's centre (the centre's own pixel
        always does). Discs are clipped to the mask.

    Returns
    -------
    ndarray of shape (H, W), bool

    Examples
    --------
    >>> int(draw_discs(np.array([[5.0, 5.0]]), (10, 10)).sum())
    9
    """
    h, w = int(shape[0]), int(shape[1])
    mask = np.zeros((h, w), bool)
    p = np.asarray(points, float).reshape(-1, 2)
    if not len(p):
        return mask
    r = np.broadcast_to(np.asarray(radius, float), (len(p),))
    if not (np.isfinite(r).all() and (r >= 0).all()):
        raise ValueError(f"radius must be finite numbers >= 0, got {radius!r}")
    reach = int(np.ceil(r.max())) + 1
    off = np.arange(-reach, reach + 1)
    cx, cy = np.rint(p[:, 0]).astype(np.int64), np.rint(p[:, 1]).astype(np.int64)
    cols = cx[:, None, None] + off[None, None, :]                       # (N, 1, K)
    rows = cy[:, None, None] + off[None, :, None]                       # (N, K, 1)
    inside = ((cols - p[:, 0, None, None]) ** 2 + (rows - p[:, 1, None, None]) ** 2
              <= (r ** 2)[:, None, None])
    inside |= (rows == cy[:, None, None]) & (cols == cx[:, None, None])
    inside &= (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
    rr, cc = np.broadcast_arrays(rows, cols)
    mask[rr[inside], cc[inside]] = True
    return mask


def _regions(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(centroids (n, 2) as (x, y), areas (n,)) of the 8-connected regions of ``mask``,
    in raster order of their first pixel (scikit-image's ``label`` order)."""
    n, labels, stats, centroids = cv2.connectedComponentsWithStats(
        mask.astype(np.uint8), connectivity=8, ltype=cv2.CV_32S)
    if n <= 1:
        return np.zeros((0, 2)), np.zeros(0, np.int64)
    flat = labels.ravel()
    on = np.flatnonzero(flat)
    first = np.full(n, flat.size, np.int64)
    np.minimum.at(first, flat[on], on)
    order = np.argsort(first[1:], kind="stable") + 1
    return centroids[order], stats[order, cv2.CC_STAT_AREA].astype(np.int64)


def _match(truth_xy: np.ndarray, pred_xy: np.ndarray, distance: float) -> np.ndarray:
    """Which predicted regions the truth targets take, greedily in order (the field's
    rule); returns a bool array over the predicted regions. One loop over the few truth
    targets of an image, the distances to every predicted region at once."""
    taken = np.zeros(len(pred_xy), bool)
    if not len(truth_xy) or not len(pred_xy):
        return taken
    near = np.hypot(*(truth_xy[:, None, :] - pred_xy[None]).transpose(2, 0, 1)) < distance
    for row in near:
        free = np.flatnonzero(row & ~taken)
        if len(free):
            taken[free[0]] = True
    return taken


def pd_fa(predicted: np.ndarray, truth: np.ndarray, *, distance: float = 3.0) -> dict:
    """Target-level Pd and pixel-level Fa of predicted masks against truth masks.

    Parameters
    ----------
    predicted, truth : ndarray of shape (T, H, W) or (H, W), bool
        One predicted and one truth mask per image.
    distance : float
        Centroid distance in px below which a predicted region detects a truth target
        (``pyirstdmetrics``' ``distance_threshold``, 3 there).

    Returns
    -------
    dict
        ``images``, ``targets`` (truth regions), ``detected``, ``irstd_pd`` = detected /
        targets (NaN without targets), ``regions`` (predicted regions), ``false_pixels``
        (pixels of the regions no target took), ``pixels`` (all pixels), ``irstd_fa`` =
        false_pixels / pixels, ``distance_px``.

    Notes
    -----
    The definition of ``pyirstdmetrics.ProbabilityDetectionAndFalseAlarmRate(num_bins=1,
    distance_threshold=distance)`` fed ``update(predicted, truth)`` image by image, computed
    with OpenCV's connected components; ``tests/test_irstd.py`` compares the two.

    Examples
    --------
    >>> truth = draw_discs(np.array([[10.0, 10.0]]), (32, 32))[None]
    >>> pred = draw_discs(np.array([[11.0, 10.0], [25.0, 5.0]]), (32, 32))[None]
    >>> s = pd_fa(pred, truth)
    >>> s["irstd_pd"], s["false_pixels"], s["pixels"]
    (1.0, 9, 1024)
    """
    pred = np.asarray(predicted, bool)
    tru = np.asarray(truth, bool)
    if pred.shape != tru.shape or pred.ndim not in (2, 3):
        raise ValueError(f"predicted and truth must be masks of one shape (T, H, W) or "
                         f"(H, W), got {pred.shape} and {tru.shape}")
    if not (np.isfinite(distance) and distance > 0):
        raise ValueError(f"distance must be a positive number, got {distance!r}")
    if pred.ndim == 2:
        pred, tru = pred[None], tru[None]
    counts = np.array([_count(p, t, distance) for p, t in zip(pred, tru)]).reshape(-1, 4)
    return _scores(counts.sum(0), len(pred), int(pred.size), distance)


def _count(pred: np.ndarray, truth: np.ndarray, distance: float) -> tuple[int, int, int, int]:
    """(truth targets, detected, predicted regions, false pixels) of one image."""
    t_xy, _ = _regions(truth)
    p_xy, p_area = _regions(pred)
    taken = _match(t_xy, p_xy, distance)
    return len(t_xy), int(taken.sum()), len(p_xy), int(p_area[~taken].sum())


def _scores(counts, images: int, pixels: int, distance: float) -> dict:
    targets, detected, regions, false_px = (int(c) for c in counts)
    return {"images": int(images), "targets": targets, "detected": detected,
            "irstd_pd": detected / targets if targets else float("nan"),
            "regions": regions, "false_pixels": false_px, "pixels": int(pixels),
            "irstd_fa": false_px / pixels if pixels else float("nan"),
            "distance_px": float(distance)}


def truth_at(truth: np.ndarray, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each target's true position at (fractional) frame times.

    Parameters
    ----------
    truth : structured ndarray with fields ``frame``, ``target``, ``x``, ``y``
        ``irdetect.tables.TRUTH`` rows.
    times : ndarray of shape (K,)
        Frame times; a time between two frames takes the position interpolated linearly
        between them, or the one frame's position where the target is in only one.

    Returns
    -------
    image : ndarray of shape (M,), int
        Index into ``times`` of each position.
    xy : ndarray of shape (M, 2)
        (x, y) px of every target present at that time.
    """
    tru = np.asarray(truth)
    t = np.asarray(times, float)
    if not len(tru) or not len(t):
        return np.zeros(0, np.int64), np.zeros((0, 2))
    ids = np.unique(tru["target"])
    lo, hi = np.floor(t).astype(np.int64), np.ceil(t).astype(np.int64)
    # (target, frame) -> row, by one sorted key
    span = int(tru["frame"].max()) + 2
    key = np.searchsorted(ids, tru["target"]) * span + tru["frame"]
    order = np.argsort(key, kind="stable")
    keys = key[order]

    def find(frames):                           # rows (targets x times), -1 when absent
        k = np.arange(len(ids))[:, None] * span + np.clip(frames, -1, span - 1)[None]
        at = np.clip(np.searchsorted(keys, k), 0, len(keys) - 1)
        ok = (keys[at] == k) & (frames >= 0)[None]
        return np.where(ok, order[at], -1)

    a, b = find(lo), find(hi)
    w = np.broadcast_to(t - lo, a.shape)
    present = (a >= 0) | (b >= 0)
    a, b = np.where(a >= 0, a, b), np.where(b >= 0, b, a)
    x = (1 - w) * tru["x"][a] + w * tru["x"][b]
    y = (1 - w) * tru["y"][a] + w * tru["y"][b]
    target_idx, image = np.nonzero(present)
    return image, np.column_stack([x[target_idx, image], y[target_idx, image]])


def _images(points_image, points_xy, radius, truth_image, truth_xy, n_images, shape,
            distance, truth_radius):
    """Draw and score one image at a time (the masks of a whole sequence are not held)."""
    if not (np.isfinite(distance) and distance > 0):
        raise ValueError(f"distance must be a positive number, got {distance!r}")
    r = np.broadcast_to(np.asarray(radius, float), (len(points_xy),))
    p_order, t_order = np.argsort(points_image, kind="stable"), np.argsort(truth_image,
                                                                           kind="stable")
    p_cut = np.searchsorted(points_image[p_order], np.arange(n_images + 1))
    t_cut = np.searchsorted(truth_image[t_order], np.arange(n_images + 1))
    counts = np.zeros(4, np.int64)
    for k in range(n_images):                   # one mask per image, its discs at once
        ps, ts = p_order[p_cut[k]:p_cut[k + 1]], t_order[t_cut[k]:t_cut[k + 1]]
        counts += _count(draw_discs(points_xy[ps], shape, r[ps]),
                         draw_discs(truth_xy[ts], shape, truth_radius), distance)
    return _scores(counts, n_images, n_images * int(shape[0]) * int(shape[1]), distance)


def score_irstd_detections(detections: np.ndarray, truth: np.ndarray, *, n_frames: int,
                           length: int, step: int, shape: tuple[int, int],
                           distance: float = 3.0, radius: float = POINT_RADIUS,
                           truth_radius: float = POINT_RADIUS, tail: bool = False) -> dict:
    """IRSTD Pd and Fa of ``/detections`` (``irdetect process``), one image per window.

    Parameters
    ----------
    detections : structured ndarray with fields ``x``, ``y``, ``combined_frame``
        ``irdetect.tables.DETECTION`` rows (x = column, y = row, px), each reported at its
        window's middle time.
    truth : structured ndarray
        ``irdetect.tables.TRUTH`` rows; each window's truth image holds the targets at the
        window's middle time, its first frame + (length - 1) / 2.
    n_frames, length, step : int
        The sequence length and the combined-frame windows.
    tail : bool
        The run had the tail window over the last ``length`` frames
        (``irdetect.combine.window_starts``).
    shape : (int, int)
        Frame (H, W).
    distance : float
        Centroid distance threshold in px (the field's 3).
    radius, truth_radius : float
        Radii in px of the discs a detection and a true position are drawn as.

    Returns
    -------
    dict
        As :func:`pd_fa`, the images being the windows.
    """
    starts = window_starts(int(n_frames), length=length, step=step, tail=tail)
    det = np.asarray(detections)
    det = det[(det["combined_frame"] >= 0) & (det["combined_frame"] < len(starts))]
    t_image, t_xy = truth_at(truth, starts + (length - 1) / 2)
    return _images(det["combined_frame"].astype(np.int64), np.column_stack([det["x"], det["y"]]),
                   radius, t_image, t_xy, len(starts), shape, distance, truth_radius)


def score_irstd_points(points: np.ndarray, truth: np.ndarray, *, n_frames: int,
                       shape: tuple[int, int], distance: float = 3.0,
                       truth_radius: float = POINT_RADIUS) -> dict:
    """IRSTD Pd and Fa of ``/track_points`` (``irdetect track``), one image per frame.

    Parameters
    ----------
    points : structured ndarray with fields ``frame``, ``x``, ``y``, ``area``
        ``irdetect.tables.TRACK_POINT`` rows (x = column, y = row, px); each is drawn as a
        disc of its region's ``area`` (px) on its centroid, or of radius
        :data:`POINT_RADIUS` where the area is unknown (NaN, 0: a coasted point).
    truth : structured ndarray
        ``irdetect.tables.TRUTH`` rows.
    n_frames : int
        Frames of the sequence (the images).
    shape : (int, int)
        Frame (H, W).
    distance, truth_radius : float
        As :func:`score_irstd_detections`.

    Returns
    -------
    dict
        As :func:`pd_fa`, the images being the frames.
    """
    pts = np.asarray(points)
    pts = pts[(pts["frame"] >= 0) & (pts["frame"] < n_frames)]
    area = np.asarray(pts["area"], float)
    radius = np.where(np.isfinite(area) & (area > 0), np.sqrt(np.where(area > 0, area, 0)
                                                              / np.pi), POINT_RADIUS)
    tru = np.asarray(truth)
    tru = tru[(tru["frame"] >= 0) & (tru["frame"] < n_frames)]
    return _images(pts["frame"].astype(np.int64), np.column_stack([pts["x"], pts["y"]]),
                   radius, tru["frame"].astype(np.int64),
                   np.column_stack([tru["x"], tru["y"]]), int(n_frames), shape, distance,
                   truth_radius)


def irstd_section(results, truth: np.ndarray, ctx: dict, path=None) -> dict:
    """``irdetect evaluate --irstd``: IRSTD Pd / Fa of a results file's ``/track_points``
    (``irdetect track``, per frame) or else its ``/detections`` (per window).

    ``ctx`` holds n_frames, length, step, tail, shape (H, W) and gate (the distance
    threshold).

    Raises
    ------
    InputError
        Neither table is in the results file.
    """
    from irdetect.errors import InputError

    if "track_points" in results:
        return score_irstd_points(results["track_points"], truth, n_frames=ctx["n_frames"],
                                  shape=ctx["shape"], distance=ctx["gate"])
    if "detections" in results:
        return score_irstd_detections(results["detections"], truth, n_frames=ctx["n_frames"],
                                      length=ctx["length"], step=ctx["step"],
                                      shape=ctx["shape"], distance=ctx["gate"],
                                      tail=ctx["tail"])
    raise InputError("--irstd needs /detections or /track_points", path)
