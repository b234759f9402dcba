"""Robust statistics shared by the stages: median, MAD sigma, and per-tile estimates.

The CFAR steps of irdetect (``irdetect.detect``, ``irdetect.verify.standardise``,
``irdetect.suppress.noise_sigma``) measure a robust location and scale per tile of a frame
and interpolate between tile centres. The tiling here takes any frame size: a side of
``n`` px is cut into ``max(1, n // tile)`` tiles of ``n // (n // tile)`` px (the last
``n mod`` px of the side join no tile's statistics but get the interpolated value).
"""

from __future__ import annotations

import cv2
import numpy as np

#: 1.4826 * MAD is the standard deviation of a Gaussian.
MAD_TO_SIGMA = 1.4826
#: the upper quartile of a Gaussian, in standard deviations
UPPER_QUARTILE_Z = 0.6745


def sorted_median(v: np.ndarray, overwrite: bool = False) -> np.ndarray:
    """``np.median(v, axis=-1)`` (same values) by a full sort, which numpy vectorises:
    about 10x faster than np.median's partition on many short rows. ``overwrite``: sort
    ``v`` (a contiguous array) in place, as ``np.median``'s ``overwrite_input``: no copy."""
    if overwrite:
        v.sort(axis=-1)
    else:
        v = np.sort(v, axis=-1)
    n = v.shape[-1]
    if n % 2:
        return v[..., n // 2]
    return (v[..., n // 2 - 1] + v[..., n // 2]) / v.dtype.type(2)


def median(v: np.ndarray):
    """``np.median(v)`` (same value) of one finite float array, by ``np.partition`` of its
    middle element(s): about 6x faster than np.median on a few thousand values (no NaN
    scan; one selection)."""
    v = np.asarray(v).ravel()
    n = len(v)
    if n % 2:
        return np.partition(v, n // 2)[n // 2]
    lo, hi = np.partition(v, (n // 2 - 1, n // 2))[n // 2 - 1:n // 2 + 1]
    return (lo + hi) / v.dtype.type(2)


def median_mad_sigma(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Median and robust sigma of every row (last axis) of ``v``.

    sigma = 1.4826 x MAD (the standard deviation of a Gaussian); where the MAD is 0 (more
    than half a row equal, e.g. quantised flat patches) 1.2533 x the mean absolute
    deviation is taken instead (the same for a Gaussian). Shared by the noise estimates of
    every stage (``noise_sigma``, ``irdetect.detect``, ``irdetect.verify``).
    """
    med = sorted_median(v)
    dev = np.abs(v - np.asarray(med)[..., None])
    sigma = np.asarray(MAD_TO_SIGMA * sorted_median(dev))
    flat = sigma <= 0
    if flat.any():
        sigma = np.where(flat, 1.2533 * dev.mean(axis=-1), sigma)
    return med, sigma


def upper_sigma(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Median and upper spread of every row (last axis) of ``v``: the distance from the
    median to the upper quartile in Gaussian standard deviations, (q75 - q50) / 0.6745.
    A long lower tail does not widen it, as it widens 1.4826 x MAD (both sides); the scale
    of a test that only high values fail (``irdetect.verify.local_significance``)."""
    q50, q75 = np.quantile(np.asarray(v, np.float64), (0.5, 0.75), axis=-1)
    return q50, (q75 - q50) / UPPER_QUARTILE_Z


def tile_grid(height: int, width: int, tile: int) -> tuple[int, int, int, int]:
    """(ny, nx, th, tw): tiles per column and row and their size in px for a frame of
    ``height`` x ``width`` px and a nominal ``tile`` (any sizes >= 1; a side shorter than
    ``tile`` is one tile)."""
    ny, nx = max(1, int(height) // int(tile)), max(1, int(width) // int(tile))
    return ny, nx, int(height) // ny, int(width) // nx


def tile_samples(a: np.ndarray, tile: int, sample: int = 1) -> np.ndarray:
    """The pixels of each tile on a ``sample``-px grid.

    Parameters
    ----------
    a : ndarray of shape (..., H, W)
    tile : int
        Nominal tile side in px (``tile_grid``).
    sample : int
        Every ``sample``-th row and column of each tile (from its first).

    Returns
    -------
    ndarray of shape (..., ny, nx, n)
        n = ceil(th / sample) x ceil(tw / sample) samples of each tile (a view when
        numpy can give one).
    """
    *lead, h, w = a.shape
    ny, nx, th, tw = tile_grid(h, w, tile)
    b = a[..., :ny * th, :nx * tw].reshape(*lead, ny, th, nx, tw)[..., ::sample, :, ::sample]
    b = np.moveaxis(b, -2, -3)                      # (..., ny, nx, th', tw')
    return b.reshape(*lead, ny, nx, -1)


def tile_map(values: np.ndarray, height: int, width: int) -> np.ndarray:
    """Per-tile values (ny, nx) interpolated bilinearly between tile centres to a
    float32 map of shape (height, width)."""
    v = np.ascontiguousarray(values, dtype=np.float32)
    return cv2.resize(v, (int(width), int(height)), interpolation=cv2.INTER_LINEAR)
