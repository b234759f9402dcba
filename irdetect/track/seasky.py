"""Sea-sky line (horizon) of a maritime frame, and the search band around it.

Cheng et al. extract the sea-sky line first (their refs [9, 11]) and look for ships near it;
the method itself is not given. We take, in every column, the row of the strongest vertical
grey step of the smoothed frame, and fit one straight line through those rows robustly
(iteratively reweighted least squares, Tukey biweight), so ships, glints and waves that win
a few columns do not tilt the line.
"""

from __future__ import annotations

import cv2
import numpy as np


def find_sea_sky_line(frame: np.ndarray, *, smooth: float = 2.0, min_step: float = 3.0,
                      iterations: int = 10) -> tuple[float, float] | None:
    """The sea-sky line of one frame as (rho, theta).

    Parameters
    ----------
    frame : ndarray of shape (H, W)
        One raw frame.
    smooth : float
        Gaussian sigma (pixels) applied before the vertical derivative.
    min_step : float
        Columns whose strongest vertical step (grey levels per pixel after smoothing) is
        below this vote for nothing; if fewer than a quarter of the columns remain there is
        no horizon and None is returned.
    iterations : int
        Reweighting passes of the robust fit.

    Returns
    -------
    (rho, theta) or None
        The line rho = x cos(theta) + y sin(theta), x = column, y = row, theta in [0, pi)
        (near pi/2 for a near-horizontal horizon), or None when no horizon is found.

    Notes
    -----
    The step's polarity is not assumed (a warm sea below a cold sky or the reverse): the
    sign taken is the one most columns agree on. Row positions are refined to sub-pixel
    by a parabola through the derivative peak.
    """
    img = np.asarray(frame)
    if img.ndim != 2 or min(img.shape) < 3:
        raise ValueError(f"frame must be 2-D with both sides >= 3, got shape {img.shape}")
    if not smooth > 0:
        raise ValueError(f"smooth must be > 0, got {smooth!r}")
    if iterations < 1:
        raise ValueError(f"iterations must be >= 1, got {iterations!r}")
    return _find_line(img.astype(np.float32, copy=False), smooth, min_step, iterations)


def _find_line(img, smooth, min_step, iterations):
    h, w = img.shape
    blur = cv2.GaussianBlur(img, (0, 0), sigmaX=smooth * 2, sigmaY=smooth)
    dy = cv2.Sobel(blur, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    dy[:2], dy[-2:] = 0, 0
    cols = np.arange(w)
    best = []
    for sign in (1.0, -1.0):
        rows = np.argmax(sign * dy, axis=0)
        best.append((np.median(sign * dy[rows, cols]), sign, rows))
    _, sign, rows = max(best, key=lambda b: b[0])
    peak = sign * dy[rows, cols]
    ok = (peak >= min_step) & (rows > 0) & (rows < h - 1)
    if ok.sum() < max(w // 4, 2):
        return None
    x, r = cols[ok], rows[ok]
    lo, mid, hi = sign * dy[r - 1, x], sign * dy[r, x], sign * dy[r + 1, x]
    denom = lo - 2 * mid + hi
    off = np.where(denom < 0, 0.5 * (lo - hi) / np.where(denom < 0, denom, -1.0), 0.0)
    y = r + np.clip(off, -0.5, 0.5)
    a, b = _robust_fit(x.astype(float), y, iterations)
    norm = np.hypot(a, 1.0)
    theta = float(np.arctan2(1.0, -a))          # normal (-a, 1) / norm; in (0, pi)
    rho = float(b / norm)
    return rho, theta


def _robust_fit(x, y, iterations):
    """y = a x + b by IRLS with Tukey's biweight (c = 4.685 robust sigmas)."""
    wts = np.ones_like(x)
    a, b = 0.0, float(np.median(y))
    for _ in range(iterations):
        a, b = np.polyfit(x, y, 1, w=np.sqrt(wts))
        res = y - (a * x + b)
        s = 1.4826 * np.median(np.abs(res)) + 1e-3
        u = res / (4.685 * s)
        wts = np.where(np.abs(u) < 1, (1 - u ** 2) ** 2, 0.0)
        if wts.sum() < 2:
            break
    return float(a), float(b)


def line_rows(line: tuple[float, float], width: int) -> np.ndarray:
    """Row y of the line at every column x = 0 .. width-1 (the line must not be vertical)."""
    rho, theta = line
    x = np.arange(width, dtype=float)
    return (rho - x * np.cos(theta)) / np.sin(theta)


def sea_sky_band(line: tuple[float, float] | None, shape: tuple[int, int], *,
                 above: float = 5.0, below: float = 40.0) -> np.ndarray | None:
    """Boolean mask of shape (H, W): rows from ``above`` px above to ``below`` px below the line.

    Returns None (search everywhere) when ``line`` is None.
    """
    if line is None:
        return None
    if above < 0 or below < 0:
        raise ValueError(f"above and below must be >= 0, got {above!r}, {below!r}")
    h, w = shape
    y0 = line_rows(line, w)
    rows = np.arange(h, dtype=float)[:, None]
    return (rows >= y0[None, :] - above) & (rows <= y0[None, :] + below)
