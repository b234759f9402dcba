"""Directional threshold detection on a combined frame (Wan & Askar 2008, section 3.1).

Every pixel is hypothesised to lie on one of 4 short straight trajectories through it
(0, 45, 90 and 135 degrees, the paper's Fig. 2); the samples along each are merged
(summed: the paper's "spatial diversity") and compared with a threshold. Here the
threshold is CFAR-style: k times a robust sigma of the merged response, measured on the
frame itself (globally or per tile).
"""

from __future__ import annotations

import functools

from dataclasses import dataclass

import cv2
import numpy as np

from irdetect.robust import median_mad_sigma, tile_map, tile_samples
from irdetect.suppress import DIRECTIONS

#: direction index -> angle of the paper's 4 hypothesised trajectories in degrees,
#: atan2(dy, dx) in the (x, y) pixel frame (x = column, y = row pointing down: 45 degrees
#: runs down-right on the screen, 135 degrees down-left)
DIRECTION_DEGREES = (0, 45, 90, 135)
SIGMA_MODES = ("global", "local")


@dataclass(frozen=True)
class DirectionalDetection:
    """The first detection of one combined frame.

    Attributes
    ----------
    mask : ndarray of bool of shape (H, W)
        Candidate pixels: the best direction's response exceeds ``k``.
    direction : ndarray of int8 of shape (H, W)
        Index into ``DIRECTION_DEGREES`` of the winning direction; -1 off the mask.
    response : ndarray of float32 of shape (H, W)
        The winning direction's standardised response (merged sum minus its robust
        location, over its robust sigma): the CFAR statistic compared with ``k``.
    """

    mask: np.ndarray
    direction: np.ndarray
    response: np.ndarray

    @property
    def count(self) -> int:
        """Number of candidate pixels."""
        return int(self.mask.sum())


def direction_degrees(directions: int = 4) -> np.ndarray:
    """Angle in degrees of each direction index: i x 180 / directions (4 -> 0, 45, 90, 135)."""
    return np.arange(directions) * 180.0 / directions


def line_kernels(window: int, directions: int = 4) -> list[np.ndarray]:
    """Line kernels of length ``window`` through the centre, one per direction.

    Each is an ndarray of float32 of shape (window, window); row index is y (down),
    column index is x (right). With 4 directions they are the paper's exact pixel lines
    (0, 45, 90, 135 degrees, ones on the line); other directions sample the line at unit
    steps with bilinear weights, so every kernel sums to ``window``.
    """
    _check_window(window)
    return [k.copy() for k in _kernels(int(window), int(directions))]


@functools.lru_cache(maxsize=16)
def _kernels(window: int, directions: int) -> tuple:
    """``line_kernels``, built once per (window, directions) of a run (read-only)."""
    r = window // 2
    out = []
    for deg in direction_degrees(directions):
        a = np.deg2rad(deg)
        dx, dy = np.cos(a), np.sin(a)
        k = np.zeros((window, window), np.float32)
        if directions == 4:
            dx, dy = round(dx), round(dy)
            for s in range(-r, r + 1):
                k[r + s * dy, r + s * dx] = 1.0
        else:
            for s in range(-r, r + 1):
                # place unit samples on the line with bilinear weights; the sample is kept
                # inside the kernel's square
                x, y = np.clip(r + s * dx, 0, window - 1), np.clip(r + s * dy, 0, window - 1)
                x0, y0 = int(np.floor(x)), int(np.floor(y))
                fx, fy = x - x0, y - y0
                for xx, yy, wgt in ((x0, y0, (1 - fx) * (1 - fy)), (x0 + 1, y0, fx * (1 - fy)),
                                    (x0, y0 + 1, (1 - fx) * fy), (x0 + 1, y0 + 1, fx * fy)):
                    if wgt > 1e-9:
                        k[yy, xx] += wgt
        k.flags.writeable = False
        out.append(k)
    return tuple(out)


def detect(combined, *, window: int = 3, k: float = 2.5, sigma: str = "local",
           tile: int = 32, smooth: float = 0.0, directions: int = 4,
           sample: int = 2) -> DirectionalDetection:
    """Directional CFAR threshold detection on one combined frame.

    Parameters
    ----------
    combined : ndarray of shape (H, W)
        A combined frame (``irdetect.combine.combine``) of suppressed frames.
    window : int
        Odd length in pixels of the 4 line hypotheses through each pixel (>= 3); 1 (beyond
        the paper) tests each pixel's own value, one direction (index 0): the fast band's
        merit, whose dilations make neighbouring pixels alike, is a point test.
    k : float
        Threshold in robust sigmas of the merged response (> 0).
    sigma : {"local", "global"}
        ``local``: robust location and sigma per ``tile`` x ``tile`` block, interpolated
        (adapts to clutter that varies across the frame); ``global``: one per frame.
    tile : int
        Block size for ``sigma="local"`` (>= 8).
    smooth : float
        Standard deviation in px of a Gaussian pre-filter matched to the target's
        point-spread function (0 = none). Beyond the paper: it collects the energy of a
        streak that runs a little off the 4 hypothesised directions or across pixels.
    directions : int
        Number of line directions, evenly spaced over 180 degrees (>= 2). The paper has
        4; more directions keep a long ``window`` aligned with streaks of any heading
        (``direction_degrees``).
    sample : int
        The robust location and sigma are measured on every ``sample``-th pixel in
        each direction (>= 1); their sort is the stage's main cost (2: a quarter of the
        pixels; the ``fast`` profile takes 4).

    Returns
    -------
    DirectionalDetection
        Candidate mask, winning direction and standardised response, each (H, W).

    Notes
    -----
    For pixel (x, y) and direction d with unit step (dx, dy), the merged response is
    S_d(x, y) = sum_{s=-r..r} C(x + s dx, y + s dy), r = window // 2 (computed with
    ``cv2.filter2D``). The paper compares the merged value with "a preset threshold";
    we standardise each direction, z_d = (S_d - median S_d) / (1.4826 MAD S_d), and keep
    pixels with max_d z_d > k, so the false-alarm rate stays put when the noise level
    or the combined-frame projection changes (CFAR). The winning direction is argmax_d
    z_d. Constant frames give no candidates (z = 0 everywhere).

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> c = rng.normal(size=(64, 64)).astype(np.float32)
    >>> c[30, 20:40] += 3.0                      # a horizontal streak
    >>> det = detect(c, window=7, k=4.0)
    >>> int(det.direction[30, 30]), DIRECTION_DEGREES[det.direction[30, 30]]
    (0, 0)
    """
    arr = np.asarray(combined)
    if arr.ndim != 2 or arr.size == 0:
        raise ValueError(f"combined must have shape (H, W), got {arr.shape}")
    _check_window(window, smallest=1)
    if not np.isfinite(k) or k <= 0:
        raise ValueError(f"k must be a positive number, got {k!r}")
    if sigma not in SIGMA_MODES:
        raise ValueError(f"sigma must be one of {SIGMA_MODES}, got {sigma!r}")
    if int(tile) != tile or tile < 8:
        raise ValueError(f"tile must be an integer >= 8, got {tile!r}")
    if int(directions) != directions or directions < 2:
        raise ValueError(f"directions must be an integer >= 2, got {directions!r}")
    if not np.isfinite(smooth) or smooth < 0:
        raise ValueError(f"smooth must be a number >= 0, got {smooth!r}")
    if int(sample) != sample or sample < 1:
        raise ValueError(f"sample must be an integer >= 1, got {sample!r}")
    img = np.ascontiguousarray(arr, dtype=np.float32)
    if not np.isfinite(img).all():
        img = np.where(np.isfinite(img), img, np.float32(0.0)).astype(np.float32)
    if smooth > 0:
        img = cv2.GaussianBlur(img, (0, 0), float(smooth), borderType=cv2.BORDER_REFLECT)
    return _detect(img, int(window), float(k), sigma, int(tile), int(directions), int(sample))


def _detect(img, window, k, sigma, tile, directions, sample=2):
    h, w = img.shape
    if window == 1:
        # no line to sum along: the frame's own values, one "direction"
        s = img[None].copy()
    else:
        kernels = _kernels(window, directions)
        # every direction's merged sum in one stack, so the tile statistics of all of
        # them come from one sort
        s = np.empty((len(kernels), h, w), np.float32)
        for d, kern in enumerate(kernels):
            cv2.filter2D(img, cv2.CV_32F, kern, dst=s[d], borderType=cv2.BORDER_REFLECT)
    best = best_dir = better = change = None
    for d, (loc, scale) in enumerate(_location_scale(s, sigma, tile, sample)):
        z = s[d]
        np.subtract(z, loc, out=z)
        np.divide(z, scale, out=z)
        if best is None:
            best, best_dir = z, np.zeros(z.shape, np.int8)
            better, change = np.empty(z.shape, bool), np.empty(z.shape, np.int8)
        else:
            np.greater(z, best, out=better)
            np.maximum(best, z, out=best)
            # best_dir = d where better, by arithmetic: a masked store (copyto where=)
            # costs 40 times more on a noise-like mask
            np.subtract(np.int8(d), best_dir, out=change)
            np.multiply(change, better, out=change)
            np.add(best_dir, change, out=best_dir)
    mask = best > k
    # -1 off the mask: (best_dir + 1) x mask - 1
    np.add(best_dir, np.int8(1), out=best_dir)
    np.multiply(best_dir, mask, out=best_dir)
    np.subtract(best_dir, np.int8(1), out=best_dir)
    return DirectionalDetection(mask=mask, direction=best_dir, response=best.copy())


def _location_scale(s: np.ndarray, sigma: str, tile: int, sample: int = 2):
    """Robust location and scale of each direction's merged sum, s of shape (D, H, W).

    Returns a list of D pairs (location, scale): float32 scalars (``global``) or (H, W)
    maps (``local``, bilinear between tile centres).
    """
    tiny = np.float32(np.finfo(np.float32).tiny)
    n_dir, h, w = s.shape
    if sigma == "global" or (h < 2 * tile and w < 2 * tile):
        med, sc = median_mad_sigma(s[:, ::sample, ::sample].reshape(n_dir, -1))
        sc = np.maximum(sc, tiny)
        return [(np.float32(m), np.float32(c)) for m, c in zip(med, sc)]
    # every sample-th pixel in each direction: the median and MAD of a tile need no
    # more, and this is the stage's main cost
    blocks = tile_samples(s, tile, sample)
    med, sc = median_mad_sigma(blocks)
    out = []
    for d in range(n_dir):
        # a tile of pure quantisation steps (MAD 0) must not give a near-zero scale:
        # floor each tile at a quarter of the median tile scale
        floor = max(0.25 * float(np.median(sc[d])), float(tiny))
        scd = np.maximum(sc[d], floor)
        out.append((tile_map(med[d], h, w), tile_map(scd, h, w)))
    return out


def _check_window(window, smallest: int = 3):
    if int(window) != window or window < smallest or window % 2 == 0:
        raise ValueError(f"window must be an odd integer >= {smallest}, got {window!r}")
