"""Candidate regions from the per-frame detector of ``irdetect process`` (issue 28).

The tracker's default front end is the per-frame path's detector, not a second one: each
window of ``length`` frames is suppressed by ``irdetect.suppress.suppress`` (default
``auto``: the temporal background while the camera holds still, the registered one when it
moves, with the camera's offsets of ``irdetect.camera.CameraMotion``), every suppressed
frame is smoothed by the PSF's Gaussian and divided by its local robust noise per 32-px
tile (``irdetect.verify.matched_frame``, ``irdetect.verify.standardise``: a value is a
local SNR in matched-filter sigmas), and its CFAR peaks are the local maxima at or above
the level a stated white-noise rate per frame sets (``irdetect.peaks.frame_level``,
``irdetect.peaks.frame_peaks``). This is what ``irdetect.pipeline.combined.front`` does,
with two departures (``detector_blocks``): the offsets the tracks' scene coordinates take
stay put over a window where ``auto`` found the camera's offsets moving but took the
image-fixed background (``irdetect.suppress.prefer_registered``: such offsets followed the
targets or clouds, not the camera), and the first window's frames take the frames after it
as the start of their past (a short past holds a slow target a pixel or two away).

Cheng et al.'s association also needs region features (grey g, area s, shape), which a peak
alone lacks. Each peak's region is measured on the same standardised frame S
(``peak_regions``):

* the **region** of a peak of value P: the 8-connected component holding the peak of the
  pixels with S >= ``fraction`` x P' (P' the highest value of the pixels connected to the
  peak at S >= ``fraction`` x k, k the CFAR level: the half-maximum region of a Gaussian
  blob at the default 0.5); peaks whose regions are one component make one region;
* **area** s: its pixel count (px);
* **grey** g: the mean of S over it (local SNR, matched-filter sigmas: the same on any
  sensor, so the FCM's ``grey_scale`` is in sigmas directly);
* **position** (x, y): the centroid of its pixels weighted by S (x = column, y = row, px);
* **shape**: sqrt(l2 / l1) of the S-weighted second central moments of its pixels,
  l1 >= l2 their eigenvalues (1 for a round blob, towards 0 for a line; 1 for a single
  pixel);
* **contrast**: the highest S in it (the peak's local SNR);
* the bounding box of its pixels.

Coordinates: x = column, y = row, px, in the image; the camera's offsets C_t (x, y px; a
scene point at p in frame 0 is at p + C_t in frame t) come with each block.
"""

from __future__ import annotations

import logging
from typing import Iterator

import cv2
import numpy as np

from irdetect.binning import sequence_floor
from irdetect.gain import STEP
from irdetect.peaks import RING_PX, frame_peaks
from irdetect.suppress import (camera_moves, future_frames, past_frames,
                               prefer_registered, suppress)
from irdetect.track.regions import REGION
from irdetect.verify import matched_frame, standardise

log = logging.getLogger(__name__)

#: the suppressor's settings the tracker uses unless given (``irdetect.config.SuppressConfig``)
SUPPRESS_DEFAULTS = dict(method="auto", size=9, guard=1, history=12, gap=8, tolerance=1,
                         fixed_pattern=True, samples=3, lead_in="future")


def detector_blocks(frames, *, length: int = 12, psf: float = 1.0, tile: int = 32,
                    suppression: dict | None = None) -> Iterator[tuple]:
    """The matched, standardised residual of a sequence, one window at a time.

    Parameters
    ----------
    frames : ndarray of shape (T, H, W), irdetect.io.FrameSource or irdetect.binning.Binned
        Raw frames; anything with ``len()``, ``.shape`` and slicing.
    length : int
        Frames per window (the combined-frame path's 12): the noise scale is measured per
        window, the suppressor streams window by window.
    psf : float
        Sigma (px) of the PSF's Gaussian, the matched filter (the tracker's 1 px;
        ``process``'s ``combine.dp_smooth`` is 0.6 px).
    tile : int
        Side (px) of the tiles of the local noise scale (``irdetect.verify.standardise``).
    suppression : dict, optional
        Keywords of ``irdetect.suppress.suppress`` (``SUPPRESS_DEFAULTS`` for those not
        given), and ``gain_step`` (``SuppressConfig.gain_step``).

    Yields
    ------
    start : int
        The window's first frame.
    matched : ndarray of float32 of shape (n, H, W)
        Its matched, standardised frames (local SNR).
    offsets : ndarray of shape (n, 2)
        The offsets (x, y px) of its frames that the scene coordinates take (image minus
        offset): the camera's, except that a window on which ``auto`` took the image-fixed
        background although the offsets moved holds the last window's last offset (zeros
        unless the suppressor is ``auto`` or ``registered``).
    gains : ndarray of shape (n, 2)
        The gain and level (G_t, O_t) of its frames against frame 0's that the reader took
        back (``irdetect.gain``; (1, 0) where the camera's gain control did not step).
    """
    from irdetect.pipeline.reader import Reader     # the process command's window reader

    sp = {**SUPPRESS_DEFAULTS, **(suppression or {})}
    sp.pop("long_memory", None)          # process's long memory: the tracker has none
    sp.pop("bin", None)                  # ``irdetect.track.track`` bins the frames
    gain_step = sp.pop("gain_step", STEP)           # the reader's (``irdetect.gain``)
    n = int(frames.shape[0])
    if n == 0:
        return
    length = max(1, min(int(length), n))
    starts = range(0, n, length)
    ahead = [future_frames(start=s, stop=min(n, s + length), **sp) for s in starts]
    # the first window is suppressed backwards in time from the frames after it (its
    # frames have no past of ``history`` frames)
    back = past_frames(**sp) if sp["method"] in ("temporal", "registered", "auto") else 0
    reader = Reader(frames, past_frames(**sp), length, max(max(ahead), back),
                    camera=sp["method"] in ("auto", "registered"), gain_step=gain_step)
    scene = np.zeros((n, 2))            # the offsets the tracks' scene coordinates take
    # integer frames' quantisation (the input's, a binned block's mean holds less)
    floor = sequence_floor(frames, psf)
    for s, extra in zip(starts, ahead):
        stop = min(n, s + length)
        if s == 0 and back and stop < n:
            # a frame early in a sequence has a short past: its image-fixed background
            # is the mean of the few frames before it, which hold a slow target a pixel
            # or two away (frame 1's background is frame 0: a blob of 2.6 px moving
            # 1 px/frame all but cancels). The window's frames take the ``back`` frames
            # after it as the start of their past: frame t's background holds frames
            # 0 .. t-1 and the latest of those, so the target's own trail in it goes
            # from far ahead (frame 0) to just behind (the last frame, as in the next
            # window: its centroid does not jump there)
            raw, _ = reader.read(0, min(n, stop + back))
            after = np.arange(stop, len(raw))
            order = np.concatenate([after, np.arange(stop)])
            residual, follow = _suppress_window(raw[:stop], raw[after], raw[:0],
                                                reader.offsets[order], sp)
        else:
            block, previous = reader.read(s, min(n, stop + extra))
            camera = reader.offsets[s - len(previous):s + len(block)]
            residual, follow = _suppress_window(block[:stop - s], previous,
                                                block[stop - s:], camera, sp)
        # a window whose offsets moved while the image-fixed background was no worse
        # than the registered one holds the scene where the last window left it: those
        # offsets followed the targets themselves or clouds over a still camera (wide
        # bright blobs dragged them 0.4 px/frame), and would move and, where the
        # keyframe changes, jump the tracks' coordinates
        before = scene[s - 1] if s else np.zeros(2)
        raw_off = reader.offsets[max(s - 1, 0):stop]
        if follow:
            scene[s:stop] = before + (raw_off[-(stop - s):] - (raw_off[0] if s else 0.0))
        else:
            scene[s:stop] = before
        standardise([matched_frame(r, psf, out=r) for r in residual], tile, floor)
        yield s, residual, scene[s:stop].copy(), reader.gains[s:stop].copy()
    if steps := reader.gain_steps():
        log.info(steps)
    if repeats := reader.repeated():
        log.warning(repeats)


def _suppress_window(block, previous, following, camera, sp) -> tuple[np.ndarray, bool]:
    """(residual (n, H, W) float32, follow): one window suppressed with the settings
    ``sp``, and whether the scene coordinates follow the camera's offsets over it
    (False: ``auto`` found them moving but took the image-fixed background,
    ``irdetect.suppress.prefer_registered``). ``camera``: the offsets (x, y px) of
    previous, block and following."""
    kw = dict(previous=previous if len(previous) else None,
              following=following if len(following) else None, camera=camera)
    if sp["method"] != "auto":
        return suppress(block, **kw, **sp), True
    # auto's choice, made here so the scene coordinates follow it
    keep = min(len(previous), past_frames(**sp))
    residual = suppress(block, **kw, **{**sp, "method": "temporal"})
    if camera_moves(camera[len(previous) - keep:len(previous) + len(block)]):
        other = suppress(block, **kw, **{**sp, "method": "registered"})
        # the bright residue counted on the frames, as before: on the window's mean
        # (``process``'s) istd640-seq3-237's windows 3-4 take the registered background
        # and the rotation's residue in the strip along the frame's edge that fewer lags
        # cover becomes a track (MOTA 0.95 -> 0.48, docs/real.md "With added noise")
        if prefer_registered(other, residual, on_mean=False):
            return other, True
        return residual, False
    return residual, True


def peak_regions(matched: np.ndarray, k: float, *, fraction: float = 0.5,
                 max_peaks: int = 100) -> np.ndarray:
    """The regions of one standardised frame's CFAR peaks and their features.

    Parameters
    ----------
    matched : ndarray of shape (H, W)
        A matched, standardised frame (local SNR per pixel; ``detector_blocks``).
    k : float
        The CFAR level (``irdetect.peaks.frame_level``): peaks are the local maxima at or
        above it (``irdetect.peaks.frame_peaks``).
    fraction : float
        In (0, 1]: a region holds the pixels connected to its peak at or above this
        fraction of the highest value connected to it (module notes).
    max_peaks : int
        The most peaks of the frame (its strongest).

    Returns
    -------
    ndarray of dtype :data:`irdetect.track.regions.REGION`
        One row per region (x = column, y = row of its S-weighted centroid, px; area px;
        grey = mean S; contrast = highest S; shape in (0, 1]), in order of decreasing
        contrast.

    Examples
    --------
    >>> import numpy as np
    >>> yy, xx = np.mgrid[:40, :40]
    >>> s = 10 * np.exp(-((xx - 20) ** 2 + (yy - 12) ** 2) / 2.0).astype(np.float32)
    >>> r = peak_regions(s, 5.0)
    >>> (round(float(r["x"][0]), 2), round(float(r["y"][0]), 2), int(r["area"][0]))
    (20.0, 12.0, 5)
    """
    m = np.asarray(matched, np.float32)
    if m.ndim != 2 or m.size == 0:
        raise ValueError(f"matched must be a non-empty 2-D array, got shape {m.shape}")
    if not 0 < fraction <= 1:
        raise ValueError(f"fraction must lie in (0, 1], got {fraction!r}")
    peaks = frame_peaks([m], k, max_peaks=max_peaks)
    if not len(peaks):
        return np.zeros(0, REGION)
    h, w = m.shape
    px = np.clip(np.rint(peaks["x"]).astype(np.int64), 0, w - 1)
    py = np.clip(np.rint(peaks["y"]).astype(np.int64), 0, h - 1)
    # 1. the pixels connected to a peak at S >= fraction k, and each component's maximum
    low = (m >= np.float32(fraction * k)).view(np.uint8)
    n1, lab1 = cv2.connectedComponents(low, connectivity=8, ltype=cv2.CV_32S)
    top = np.zeros(n1, np.float32)
    flat1 = lab1.ravel()
    on = flat1 > 0
    np.maximum.at(top, flat1[on], m.ravel()[on])
    # 2. within them, the pixels at S >= fraction x their component's maximum
    keep = (lab1 > 0) & (m >= np.float32(fraction) * top[lab1])
    n2, lab2, stats, _ = cv2.connectedComponentsWithStats(keep.view(np.uint8),
                                                          connectivity=8, ltype=cv2.CV_32S)
    ids = np.unique(lab2[py, px])
    ids = ids[ids > 0]
    if not len(ids):
        return np.zeros(0, REGION)
    flat = lab2.ravel()
    sel = np.zeros(n2, bool)
    sel[ids] = True
    pix = np.flatnonzero(sel[flat])
    lab = flat[pix]
    v = m.ravel()[pix].astype(np.float64)
    ys, xs = np.divmod(pix, m.shape[1])
    n = n2
    wsum = np.bincount(lab, v, n)
    cnt = np.bincount(lab, minlength=n).astype(float)
    cx = np.bincount(lab, v * xs, n) / np.maximum(wsum, 1e-12)
    cy = np.bincount(lab, v * ys, n) / np.maximum(wsum, 1e-12)
    dx, dy = xs - cx[lab], ys - cy[lab]
    sxx = np.bincount(lab, v * dx * dx, n) / np.maximum(wsum, 1e-12)
    syy = np.bincount(lab, v * dy * dy, n) / np.maximum(wsum, 1e-12)
    sxy = np.bincount(lab, v * dx * dy, n) / np.maximum(wsum, 1e-12)
    half = 0.5 * (sxx + syy)
    rad = np.sqrt(np.maximum(0.25 * (sxx - syy) ** 2 + sxy ** 2, 0.0))
    l1, l2 = half + rad, np.maximum(half - rad, 0.0)
    shape = np.where(l1 > 1e-12, np.sqrt(l2 / np.maximum(l1, 1e-12)), 1.0)
    peak = np.zeros(n, np.float64)
    np.maximum.at(peak, lab, v)
    out = np.zeros(len(ids), REGION)
    out["x"], out["y"] = cx[ids], cy[ids]
    out["area"], out["grey"] = cnt[ids], wsum[ids] / cnt[ids]
    out["contrast"], out["shape"] = peak[ids], shape[ids]
    out["bx"], out["by"] = stats[ids, cv2.CC_STAT_LEFT], stats[ids, cv2.CC_STAT_TOP]
    out["bw"], out["bh"] = stats[ids, cv2.CC_STAT_WIDTH], stats[ids, cv2.CC_STAT_HEIGHT]
    return out[np.argsort(-out["contrast"], kind="stable")]


def guided_regions(matched: np.ndarray, found: np.ndarray, centres: np.ndarray, k: float, *,
                   radius: float, fraction: float = 0.5) -> np.ndarray:
    """Regions of the peaks at the lower level ``k`` within ``radius`` px of ``centres``
    that ``found`` lacks: a confirmed track's gate searched below the frame's CFAR level
    (beyond Cheng et al.; ``guided_rate`` of ``irdetect.track.track``).

    A frame's level keeps white noise to about one peak per frame over all its H W pixels;
    a confirmed track needs only the disc about its prediction, where the same noise
    reaches a far lower level as rarely (``irdetect.peaks.cfar_level`` of the disc's
    pixels). A target that fades below the frame's level for a while (a dim target over
    a brighter background, istd640-seq1-243) still feeds its track there.

    Parameters
    ----------
    matched : ndarray of shape (H, W)
        The matched, standardised frame (``detector_blocks``).
    found : ndarray of dtype REGION
        The regions the frame's own level gave (image px).
    centres : ndarray of shape (n, 2)
        The confirmed tracks' predicted positions (x, y) in the image, px.
    k : float
        The lower level (local SNR).
    radius : float
        Px about a centre searched.
    fraction : float
        As ``peak_regions``.

    Returns
    -------
    ndarray of dtype REGION
        The new regions (image px), none within ``radius`` of a centre that ``found``
        already has a region near.
    """
    m = np.asarray(matched, np.float32)
    h, w = m.shape
    reach = int(np.ceil(radius + RING_PX + 2))      # the point test's ring stays inside
    parts = []
    for cx, cy in np.asarray(centres, float).reshape(-1, 2):   # the confirmed tracks
        if len(found) and np.hypot(found["x"] - cx, found["y"] - cy).min() <= radius:
            continue
        if not (np.isfinite(cx) and np.isfinite(cy)):
            continue
        x0, y0 = max(0, int(cx) - reach), max(0, int(cy) - reach)
        x1, y1 = min(w, int(cx) + reach + 1), min(h, int(cy) + reach + 1)
        if x1 - x0 < 3 or y1 - y0 < 3:
            continue
        r = peak_regions(m[y0:y1, x0:x1], k, fraction=fraction, max_peaks=4)
        r["x"] += x0
        r["y"] += y0
        r["bx"] += x0
        r["by"] += y0
        parts.append(r[np.hypot(r["x"] - cx, r["y"] - cy) <= radius][:1])
    return np.concatenate(parts) if parts else np.zeros(0, REGION)
