"""Local maxima of the per-frame path (``irdetect.peaks.frame_peaks``), compiled."""

from __future__ import annotations

import numpy as np

from irdetect.kernels import jit


@jit
def local_maxima(frame, k, ys, xs):
    """Pixels of ``frame`` at or above ``k`` and at or above their 8 neighbours.

    Parameters
    ----------
    frame : float32 ndarray (H, W)
    k : float32
        The level.
    ys, xs : int64 ndarray (H W,)
        Filled with the rows and columns (y = row, x = column) of the maxima, row-major.

    Returns
    -------
    int
        The number of maxima found (the first entries of ``ys``, ``xs``).

    Notes
    -----
    Border pixels are never maxima (a peak has its 8 neighbours). One pass that replaces
    ``(m >= k) & (m >= cv2.dilate(m, ones((3, 3))))`` with the border cleared and
    ``np.nonzero`` (``tests/test_kernels.py``); most pixels fail the level and are left at
    the first comparison.
    """
    h, w = frame.shape
    n = 0
    for y in range(1, h - 1):
        above, row, below = frame[y - 1], frame[y], frame[y + 1]
        for x in range(1, w - 1):
            v = row[x]
            if v < k:
                continue
            if (v >= row[x - 1] and v >= row[x + 1]
                    and v >= above[x - 1] and v >= above[x] and v >= above[x + 1]
                    and v >= below[x - 1] and v >= below[x] and v >= below[x + 1]):
                ys[n] = y
                xs[n] = x
                n += 1
    return n


KERNELS = (local_maxima,)


def warm_up() -> None:
    """Compile or load ``local_maxima`` for float32 frames."""
    idx = np.zeros(9, np.int64)
    local_maxima(np.zeros((3, 3), np.float32), np.float32(0), idx, idx.copy())
