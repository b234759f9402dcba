"""The operating point: a score threshold set by a stated false-alarm rate, measured on the
sequence itself.

A detector's clutter does not follow the white-noise tail its first threshold assumes
(real ground, cloud edges and water glint have far heavier tails). Where the run holds a
sample of scores known to come from clutter (for the per-frame path: the tracks that do not
move against the scene, ``irdetect.pipeline.perframe``), the tail of that sample says how
often clutter reaches a score in this sequence, and the threshold is the score clutter
reaches ``rate`` times per frame.

The tail is modelled as exponential above the sample's median u (the peaks-over-threshold
model of extreme-value statistics, with the mean excess as its scale):

    N(s) = n_u exp(-(s - u) / lambda),   lambda = mean(s_i - u | s_i > u),

N(s) the clutter items per sequence at or above s, n_u those above u. The threshold is the
s at which N(s) / T = rate, T the frames of the sequence.

The combined-frame path has no such sample of known clutter, but each window holds
thousands of point-like structures of which a target is a handful: its operating point
(``integrated_map``, ``map_threshold``, ``significance``) fits the same tail to the largest
local maxima of the window's integrated, self-standardised map (docs/detection.md, "The
combined-frame path's operating point").
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from irdetect.robust import median_mad_sigma, tile_map, tile_samples

#: fewest clutter scores above the sample's median a tail is fitted to; below it the
#: floor alone applies (a scale from 2 or 3 excesses is no estimate: 2 strong chains among
#: 11 put a simulated target of SNR 8 under the threshold)
MIN_SAMPLE = 8


def tail_threshold(clutter, n_frames: int, rate: float, floor: float) -> float:
    """The score clutter of this sequence reaches ``rate`` times per frame.

    Parameters
    ----------
    clutter : array_like of shape (N,)
        Scores of items known to be clutter (higher = more target-like).
    n_frames : int
        Frames of the sequence (T >= 1).
    rate : float
        Clutter items per frame allowed at or above the threshold (> 0).
    floor : float
        The lowest threshold returned (the white-noise level).

    Returns
    -------
    float
        max(floor, u + lambda log(n_u / (rate T))) (module notes); ``floor`` when fewer
        than ``MIN_SAMPLE`` scores lie above the median or the items per frame are within
        ``rate`` already.
    """
    if not (math.isfinite(rate) and rate > 0):
        raise ValueError(f"rate must be a positive number, got {rate!r}")
    s = np.asarray(clutter, np.float64).ravel()
    s = s[np.isfinite(s)]
    if s.size <= rate * n_frames:
        return float(floor)
    u, excess = _excess(s)
    if excess.size < MIN_SAMPLE:
        return float(floor)
    scale = float(excess.mean())
    return max(float(floor), u + scale * math.log(excess.size / (rate * n_frames)))


def _excess(values: np.ndarray) -> tuple[float, np.ndarray]:
    """The tail model's median u of a sample and its values' excesses over it."""
    u = float(np.median(values)) if values.size else 0.0
    return u, values[values > u] - u


def tail_share(values, x: float) -> float:
    """The share of a sample at or above ``x``, its tail above the median taken as
    exponential.

    Parameters
    ----------
    values : array_like of shape (N,)
        The sample (N >= 1).
    x : float
        The value.

    Returns
    -------
    float
        In (0, 1]: 1 at or below the median; above it (n_u / N) exp(-(x - u) / e), u the
        median, n_u the values above it and e their mean excess over it (the tail model
        of ``tail_threshold``); the empirical share, at least 1 / N,
        when fewer than ``MIN_SAMPLE`` values lie above the median.

    Examples
    --------
    >>> round(tail_share([0.1, 0.2, 0.3, 0.4, 0.5], 0.2), 3)
    1.0
    """
    v = np.asarray(values, np.float64).ravel()
    u, excess = _excess(v)
    if x <= u:
        return 1.0
    if excess.size < MIN_SAMPLE:
        return max(int((v >= x).sum()), 1) / v.size
    return max(excess.size / v.size * math.exp(-(x - u) / float(excess.mean())), 1e-300)


# --- the combined-frame path's operating point: a CFAR on the window's integrated map ---

#: the tail of a window's integrated map is fitted to its largest local maxima: this
#: share of them, and at least MIN_TAIL (a target is a handful among thousands)
TAIL_SHARE = 0.005
MIN_TAIL = 10
#: side (px) of the neighbourhood of which a local maximum of the map is the largest
MAXIMUM_PX = 5
#: a detection's significance is at least the map's largest value within this many px of
#: it (a verified position 1-3 px off the target's peak still reads the target)
NEAR_PX = 3


def integrated_map(mean: np.ndarray, tile: int = 32):
    """A map of the matched frames' mean standardised by its own noise.

    Parameters
    ----------
    mean : ndarray of shape (H, W)
        The mean over F frames of the matched, standardised frames, each dilated by
        3 x 3 (``irdetect.pipeline.fusion.dilated_sum`` / F: the values
        ``irdetect.pipeline.fusion.track_mean`` reads).
    tile : int
        Side (px) of the tiles whose median and 1.4826 MAD standardise the mean.

    Returns
    -------
    z, centre, scale : ndarray of float32 of shape (H, W)
        z = (mean - centre) / scale, centre the median and scale the 1.4826 MAD per
        tile (bilinear between tile centres): the significance of a still point in units
        of the measured noise of the mean. On white noise the scale is one frame's sigma
        / sqrt(F); residue that persists from frame to frame (cloud and ground clutter)
        keeps it near one frame's sigma, which the white-noise scaling of the
        verification's sums cannot see.
    """
    m = np.asarray(mean, np.float32)
    h, w = m.shape
    centre, scale = median_mad_sigma(tile_samples(m, tile))
    centre = tile_map(centre, h, w)
    scale = tile_map(np.maximum(scale, np.finfo(np.float32).tiny), h, w)
    return (m - centre) / scale, centre, scale


def map_threshold(z: np.ndarray, rate: float, length: int) -> float:
    """The significance clutter of this window's map reaches ``rate`` times per frame.

    The local maxima of ``z`` (the largest of their ``MAXIMUM_PX`` square, above 0) are
    the window's point-like structures, nearly all clutter. Their tail is modelled as
    exponential (the module notes' model) above u, the largest but n_u of them (n_u =
    max(``MIN_TAIL``, ``TAIL_SHARE`` x their number)), with the scale lambda = median
    excess / ln 2 (the median of an exponential excess is lambda ln 2; a few targets far
    in the tail do not move it as they move the mean):

        threshold = u + lambda log(n_u / (rate L))

    Parameters
    ----------
    z : ndarray of shape (H, W)
        ``integrated_map``'s z.
    rate : float
        Clutter maxima per frame allowed at or above the threshold (> 0).
    length : int
        Frames of the window (L).

    Returns
    -------
    float
        The threshold; -inf when the map has ``MIN_TAIL`` maxima or fewer (too small a
        frame to measure a tail on).
    """
    if not (math.isfinite(rate) and rate > 0):
        raise ValueError(f"rate must be a positive number, got {rate!r}")
    z = np.ascontiguousarray(z, np.float32)
    peak = (z >= cv2.dilate(z, np.ones((MAXIMUM_PX, MAXIMUM_PX), np.uint8))) & (z > 0)
    v = z[peak]
    n_u = max(MIN_TAIL, int(math.ceil(TAIL_SHARE * v.size)))
    if v.size <= n_u:
        return -math.inf
    v = -np.partition(-v, n_u)[:n_u + 1]          # the n_u + 1 largest, u the last
    u = float(v[n_u])
    scale = float(np.median(v[:n_u] - u)) / math.log(2.0)
    return u + scale * math.log(n_u / (rate * length))


def significance(integrated, snr: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Detections' significance on an integrated map.

    Parameters
    ----------
    integrated : (z, centre, scale)
        ``integrated_map`` of the window.
    snr : ndarray of shape (N,)
        The detections' mean matched value along their tracks over the map's frames
        (``irdetect.pipeline.fusion.track_mean``).
    x, y : ndarray of shape (N,)
        Positions (x = column, y = row, px) at the window's middle frame.

    Returns
    -------
    ndarray of shape (N,)
        The larger of the track's mean standardised like the map, (snr - centre) /
        scale (a moving target integrates along its track, not in place), and the map's
        largest z within ``NEAR_PX`` px (a still target's own peak).
    """
    z, centre, scale = integrated
    h, w = z.shape
    col = np.clip(np.rint(x), 0, w - 1).astype(np.intp)
    row = np.clip(np.rint(y), 0, h - 1).astype(np.intp)
    side = 2 * NEAR_PX + 1
    best = cv2.dilate(np.ascontiguousarray(z), np.ones((side, side), np.uint8))[row, col]
    along = (snr - centre[row, col]) / scale[row, col]
    return np.fmax(best.astype(np.float64), along)
