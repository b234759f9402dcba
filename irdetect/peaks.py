"""Per-frame CFAR detection: the local maxima of each frame's matched, standardised residual.

The per-frame path (beyond the papers; docs/detection.md, "The per-frame path") looks at
one frame at a time where the combined-frame path integrates 12. Its input is what the
combined-frame path already computes for its verification: each suppressed frame smoothed
by the PSF's Gaussian (a matched filter) and divided by its local robust noise scale per
32-px tile (``irdetect.verify.matched_frame``, ``irdetect.verify.standardise``), so a value
is a local SNR in matched-filter sigmas. A detection is a pixel that is the largest of its
3 x 3 neighbourhood (the frame's outermost pixels, with neighbours missing, are none),
reaches the CFAR level k and is a point: nothing on a circle of ``RING_PX`` about it
reaches ``RING_RATIO`` of its value (an edge continues along itself).

The level follows from a stated false-alarm rate per frame (``cfar_level``): on white
noise a pixel exceeds k with probability Q(k) (the Gaussian tail), so a frame of N pixels
gives N Q(k) false peaks at most (fewer: a peak needs its neighbours lower). Real clutter
has heavier tails than that; the per-frame tracks (``irdetect.pipeline.perframe``) measure
them on the sequence itself.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from scipy.special import ndtri

from irdetect import tables

_NEIGHBOURS = np.ones((3, 3), np.uint8)


def cfar_level(n_pixels: int, false_rate: float, scale_error: float = 0.0) -> float:
    """The CFAR level k at which white noise gives ``false_rate`` peaks per frame.

    Parameters
    ----------
    n_pixels : int
        Pixels per frame (H W).
    false_rate : float
        False peaks per frame allowed on white noise (> 0, < n_pixels).
    scale_error : float
        Relative standard error s of the noise scale the frames were divided by (>= 0;
        ``irdetect.verify.standardise`` estimates it from ~1,000 samples per tile:
        ``STANDARDISE_ERROR``).

    Returns
    -------
    float
        k = q / sqrt(1 - q^2 s^2), q = Q^-1(false_rate / n_pixels), Q the standard normal
        tail: a pixel of noise divided by a scale off by a factor (1 + e), e ~ N(0, s^2),
        exceeds k with the probability Q(k / sqrt(1 + k^2 s^2)) (to first order), which
        is Q(q). 5.5 for 640x512 at 0.01 per frame, 5.2 for 256x256.
    """
    if not (math.isfinite(false_rate) and 0 < false_rate < n_pixels):
        raise ValueError(f"false_rate must lie in (0, {n_pixels}) per frame, got {false_rate!r}")
    q = float(-ndtri(false_rate / n_pixels))
    s = float(scale_error)
    if not (math.isfinite(s) and 0 <= s and q * s < 1):
        raise ValueError(f"scale_error must lie in [0, {1 / q:.3g}), got {scale_error!r}")
    return q / math.sqrt(1.0 - (q * s) ** 2)


#: relative standard error of ``irdetect.verify.standardise``'s noise scale: 1.4826 MAD of
#: n = 1,024 samples per 32-px tile (every 3rd of 12 frames, a 2-px grid) has a relative
#: standard error of about 1.166 / sqrt(n)
STANDARDISE_ERROR = 1.166 / math.sqrt(1024)


#: the most peaks a frame gives (its strongest): a bound on the linking's cost. A frame
#: with more is one whose background failed (a camera jump the registration missed gave
#: 10,000 on daub-data15-a), and its strongest peaks are what a target there would be among
MAX_PEAKS = 100

#: the point test: a peak is kept when the largest value on a circle of RING_PX about it
#: is under RING_RATIO of its own. An edge or ridge (a horizon the background leaves, a
#: cloud's rim) continues along itself and fails; a point target of PSF sigma up to 2.5 px
#: falls to about a third at 4 px (the combined-frame path's ring test, irdetect.verify,
#: does the same for its chains). Unregistered horizons under a pan had made hundreds of
#: per-frame tracks along the edge (bench_unseen scenes 0 and 2: 3.6 and 2.0 false per frame)
RING_PX = 4.0
RING_RATIO = 0.7
_RING = np.stack([RING_PX * np.cos(np.linspace(0, 2 * np.pi, 16, endpoint=False)),
                  RING_PX * np.sin(np.linspace(0, 2 * np.pi, 16, endpoint=False))], 1)


def frame_peaks(matched, k: float, *, first_frame: int = 0,
                max_peaks: int = MAX_PEAKS) -> np.ndarray:
    """Local maxima of matched, standardised frames at or above ``k``, with sub-pixel
    positions.

    Parameters
    ----------
    matched : sequence of ndarray of shape (H, W), float32
        Matched, standardised frames (local SNR per pixel), in time order.
    k : float
        The CFAR level (``cfar_level``).
    first_frame : int
        Frame number of ``matched[0]``.
    max_peaks : int
        The most peaks per frame: its ``max_peaks`` strongest (``MAX_PEAKS``).

    Returns
    -------
    structured ndarray
        ``irdetect.tables.FRAME_DETECTION`` rows: ``frame``, ``x``, ``y`` (x = column,
        y = row, px, sub-pixel: the vertex of the parabola through the peak and its two
        neighbours along each axis, within half a pixel), ``score`` (the peak's value, local
        SNR in matched-filter sigmas). In frame order, then row-major. Only points
        (``RING_PX``, ``RING_RATIO``).
    """
    if int(max_peaks) != max_peaks or max_peaks < 1:
        raise ValueError(f"max_peaks must be an integer >= 1, got {max_peaks!r}")
    parts = []
    for i, m in enumerate(matched):       # a loop over the frames of a window
        m = np.asarray(m, np.float32)
        peak = (m >= k) & (m >= cv2.dilate(m, _NEIGHBOURS))
        peak[[0, -1], :] = peak[:, [0, -1]] = False      # a peak has its 8 neighbours
        ys, xs = np.nonzero(peak)
        if not len(ys):
            continue
        h, w = m.shape
        ry = np.clip(np.rint(ys[:, None] + _RING[None, :, 1]), 0, h - 1).astype(np.intp)
        rx = np.clip(np.rint(xs[:, None] + _RING[None, :, 0]), 0, w - 1).astype(np.intp)
        point = m[ry, rx].max(axis=1) < RING_RATIO * m[ys, xs]
        ys, xs = ys[point], xs[point]
        c = m[ys, xs].astype(np.float64)
        if len(c) > max_peaks:
            top = np.sort(np.argpartition(-c, max_peaks - 1)[:max_peaks])
            ys, xs, c = ys[top], xs[top], c[top]
        dx = _vertex(m[ys, np.maximum(xs - 1, 0)], c, m[ys, np.minimum(xs + 1, w - 1)])
        dy = _vertex(m[np.maximum(ys - 1, 0), xs], c, m[np.minimum(ys + 1, h - 1), xs])
        parts.append(tables.from_columns(tables.FRAME_DETECTION,
                                         frame=np.full(len(ys), first_frame + i),
                                         x=xs + dx, y=ys + dy, score=c))
    return np.concatenate(parts) if parts else tables.empty(tables.FRAME_DETECTION)


def _vertex(left, centre, right) -> np.ndarray:
    """Offset in (-0.5, 0.5) of the parabola's vertex through (-1, left), (0, centre),
    (1, right); 0 where the three are flat."""
    left, right = left.astype(np.float64), right.astype(np.float64)
    curve = left - 2.0 * centre + right
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.where(curve < 0, 0.5 * (left - right) / curve, 0.0)
    return np.clip(d, -0.5, 0.5)


def frame_level(shape, false_rate: float) -> float:
    """The per-frame path's CFAR level for standardised frames of ``shape`` (H, W):
    ``cfar_level`` with ``STANDARDISE_ERROR``."""
    return cfar_level(int(shape[0]) * int(shape[1]), false_rate, STANDARDISE_ERROR)
