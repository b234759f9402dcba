"""Combined frames: project windows of consecutive (suppressed) frames into one image.

Wan & Askar (2008): "the first 12 frames of the sequence form a combined frame". A point
moving through the window leaves a streak in the combined frame, which the directional
detector (``irdetect.detect``) then integrates along its line.
"""

from __future__ import annotations

import cv2
import numpy as np

PROJECTIONS = ("max", "mean", "sum", "dp")


def window_starts(n_frames: int, *, length: int = 12, step: int = 12,
                  tail: bool = False) -> np.ndarray:
    """First frame of every full window ``[s, s + length)`` inside ``n_frames`` frames.

    The windows start every ``step`` frames from frame 0 (the paper's combined frames);
    with ``tail``, when they leave frames after the last one, one more window covers the
    sequence's last ``length`` frames, ``[n_frames - length, n_frames)`` (it overlaps
    the window before it), so that every frame lies in a window.
    """
    _check(length, step)
    if n_frames < length:
        return np.zeros(0, dtype=np.int64)
    starts = np.arange(0, n_frames - length + 1, step, dtype=np.int64)
    if tail and starts[-1] + length < n_frames:
        starts = np.append(starts, n_frames - length)
    return starts


def frames_needed(n_combined: int, *, length: int = 12, step: int = 12) -> int:
    """Frames needed for ``n_combined`` full windows."""
    _check(length, step)
    return (n_combined - 1) * step + length


def combine(frames, camera=None, *, length: int = 12, step: int = 12, tail: bool = True,
            projection: str = "dp", dp_radius: int = 1, dp_decay: float = 0.95,
            dp_smooth: float = 0.6) -> np.ndarray:
    """Project windows of ``length`` frames, every ``step`` frames, into combined frames.

    Parameters
    ----------
    frames : ndarray of shape (T, H, W)
        Suppressed frames.
    camera : ndarray of shape (T, 2), optional
        ``dp`` only: the camera's image offsets (x, y) px of the frames
        (``irdetect.camera``). The merit then follows the scene: before each frame's
        dilation it is shifted by the camera's motion since the last frame (whole
        pixels: the difference of the rounded offsets), so ``dp_radius`` bounds the
        target's speed against the scene, not in the image. The combined frame stays in
        the image coordinates of the window's last frame.
    length : int
        Frames per combined frame (paper: 12).
    step : int
        Frames between the starts of consecutive windows (paper: 12, no overlap).
    tail : bool
        When the windows leave frames after the last one, one more window over the last
        ``length`` frames (``window_starts``); false: those frames are dropped (the
        paper).
    projection : {"max", "mean", "sum", "dp"}
        Per-pixel projection over the window. ``dp`` (beyond the paper) is a dynamic-
        programming track-before-detect merit: M_0 = F_0, M_t = F_t + dp_decay x
        dilate(M_{t-1}) with a (2 dp_radius + 1)-square, F_t the frame smoothed by a
        Gaussian of ``dp_smooth`` px; M at the window's last frame is the combined frame.
        It sums a target's energy along its own path (speed up to ``dp_radius``
        px/frame) instead of the noise of every frame at every streak pixel, and puts the
        target at its position in the window's last frame.
    dp_radius : int
        ``dp``: largest motion in px per frame followed by the merit (>= 1).
    dp_decay : float
        ``dp``: forgetting factor in (0, 1]; < 1 limits how far the merit of a bright
        point spreads through the dilations.
    dp_smooth : float
        ``dp``: Gaussian pre-filter sigma in px (0 = none), matched to the target PSF.

    Returns
    -------
    ndarray of float32 of shape (K, H, W)
        K = number of windows, ``window_starts(T, length=, step=, tail=)`` (K = 0 when
        T < length).

    Notes
    -----
    The paper does not state the projection; the per-pixel maximum keeps the full peak
    of a moving point at every pixel it crosses (the mean would dilute a point moving
    1 px/frame by 1/12), at the price of raising the noise floor (the maximum of 12
    Gaussian samples has mean 1.63 sigma, sd 0.60 sigma), which the CFAR threshold of
    ``irdetect.detect`` measures and accounts for.

    Examples
    --------
    >>> import numpy as np
    >>> stack = np.zeros((24, 8, 8), np.float32); stack[3, 2, 2] = 1; stack[20, 5, 5] = 2
    >>> c = combine(stack, length=12, projection="max")
    >>> c.shape, float(c[0, 2, 2]), float(c[1, 5, 5])
    ((2, 8, 8), 1.0, 2.0)
    """
    _check(length, step)
    if projection not in PROJECTIONS:
        raise ValueError(f"projection must be one of {PROJECTIONS}, got {projection!r}")
    if int(dp_radius) != dp_radius or dp_radius < 1:
        raise ValueError(f"dp_radius must be an integer >= 1, got {dp_radius!r}")
    if not 0 < dp_decay <= 1:
        raise ValueError(f"dp_decay must be in (0, 1], got {dp_decay!r}")
    if not np.isfinite(dp_smooth) or dp_smooth < 0:
        raise ValueError(f"dp_smooth must be a number >= 0, got {dp_smooth!r}")
    arr = np.asarray(frames)
    if arr.ndim != 3:
        raise ValueError(f"frames must have shape (T, H, W), got {arr.shape}")
    starts = window_starts(len(arr), length=length, step=step, tail=tail)
    out = np.empty((len(starts),) + arr.shape[1:], dtype=np.float32)
    dp = (int(dp_radius), float(dp_decay), float(dp_smooth))
    moves = None
    if camera is not None:
        cam = np.asarray(camera, np.float64)
        if cam.shape != (len(arr), 2) or not np.isfinite(cam).all():
            raise ValueError(f"camera must be finite offsets of shape ({len(arr)}, 2), "
                             f"got {cam.shape}")
        if projection != "dp":
            raise ValueError(f"camera needs projection 'dp', got {projection!r}")
        # whole-pixel motion of the scene in the image from each frame to the next
        moves = np.diff(np.rint(cam), axis=0, prepend=np.rint(cam[:1])).astype(np.int64)
    for i, s in enumerate(starts):
        _project(arr[s:s + length], projection, out[i], dp,
                 None if moves is None else moves[s:s + length])
    return out


def _dp(block: np.ndarray, radius: int, decay: float, smooth: float, out: np.ndarray,
        moves=None) -> None:
    kern = np.ones((2 * radius + 1, 2 * radius + 1), np.uint8)
    merit = None
    for t, frame in enumerate(block):
        f = np.asarray(frame, dtype=np.float32)
        if smooth > 0:
            f = cv2.GaussianBlur(f, (0, 0), smooth, borderType=cv2.BORDER_REFLECT)
        if merit is None:
            merit = f.copy()
        else:
            merit = cv2.dilate(merit, kern, borderType=cv2.BORDER_REPLICATE)
            if moves is not None and moves[t].any():
                merit = _shifted(merit, int(moves[t, 0]), int(moves[t, 1]))
            merit *= decay
            merit += f
    out[...] = merit


def _shifted(m: np.ndarray, dx: int, dy: int) -> np.ndarray:
    """``m`` moved by (dx, dy) whole px (out[y, x] = m[y - dy, x - dx]); what comes in
    from outside is the border pixel (the merit's replicate border)."""
    h, w = m.shape
    return cv2.warpAffine(m, np.float32([[1, 0, dx], [0, 1, dy]]), (w, h),
                          flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)


def _project(block: np.ndarray, projection: str, out: np.ndarray, dp=(1, 0.95, 0.6),
             moves=None) -> None:
    if projection == "dp":
        _dp(block, *dp, out, moves)
    elif projection == "max":
        np.max(block, axis=0, out=out)
    elif projection == "mean":
        np.mean(block, axis=0, dtype=np.float32, out=out)
    else:
        np.sum(block, axis=0, dtype=np.float32, out=out)


def _check(length, step):
    if int(length) != length or length < 1:
        raise ValueError(f"length must be an integer >= 1, got {length!r}")
    if int(step) != step or step < 1:
        raise ValueError(f"step must be an integer >= 1, got {step!r}")
