"""Pixel binning of oversampled footage (beyond the papers; ``suppress.bin``).

The stages' settings in pixels hold for footage whose finest detail is about one pixel:
the matched filter of 0.6 px, the fixed pattern's 3 x 3 px high-pass, the suppression's
tolerance of 1 px, the per-frame path's position error of 1 px, the speeds in px/frame.
Footage sampled finer than its detail (an analog video digitised at twice its sensor's
resolution; a sensor whose point targets and hot pixels fill 2 x 2 px) has all of them at
the wrong scale. On the 17 real folders upsampled 2 x (cubic) the defaults met the
real-data goal on 3 of 17 instead of 11 (docs/real.md, "The sequences transformed").

Binning ``factor`` x ``factor`` blocks of pixels into one (their mean) brings such footage
to the scale the settings assume, with 1 / factor^2 of the pixels to process. The input's
last ``H mod factor`` rows and ``W mod factor`` columns join no block. Everything a run
reports is given back in the input's pixels: the binned pixel i holds the input's pixels
factor i .. factor i + factor - 1, so a binned position x is the input's
factor x + (factor - 1) / 2 (x = column, y = row), a velocity or a camera offset scales
by factor, an area by factor^2. The binned frames are float32 block means, so the gain
control's undoing (``irdetect.gain``) has no integer limits to clip them at.
"""

from __future__ import annotations

import cv2
import numpy as np

from irdetect.io.sources import FrameView
from irdetect.verify import quantisation_floor

#: per table (``irdetect.tables.BY_NAME``): its (x, y) position columns, ...
_POSITIONS = {
    "candidates": [("x", "y")], "detections": [("x", "y")],
    "combined_detections": [("x", "y")], "frame_detections": [("x", "y")],
    "frame_tracks": [("x", "y")], "track_points": [("x", "y")], "tracks": [("x0", "y0")],
    "segments": [("x1", "y1"), ("x2", "y2"), ("x3", "y3")],
}
#: ... the columns that scale by the factor (velocities, camera offsets) ...
_LINEAR = {
    "detections": ("vx", "vy"), "combined_detections": ("vx", "vy"), "segments": ("vx", "vy"),
    "tracks": ("vx", "vy"), "frame_tracks": ("vx", "vy", "svx", "svy"),
    "track_points": ("vx", "vy"), "camera": ("dx", "dy"),
}
#: ... and those that scale by its square (areas); ``tracks``' rho moves with theta
_AREAS = {"track_points": ("area",)}

#: the largest ``suppress.bin``
MAX_BIN = 16


def check_bin(factor) -> int:
    """``suppress.bin`` as an int, or ValueError naming it."""
    if isinstance(factor, bool) or int(factor) != factor or not 1 <= factor <= MAX_BIN:
        raise ValueError(f"suppress.bin must be an integer from 1 to {MAX_BIN}, "
                         f"got {factor!r}")
    return int(factor)


class Binned(FrameView):
    """A sequence seen through ``factor`` x ``factor`` pixel blocks: each frame the mean of
    its blocks, float32, (H // factor, W // factor).

    Parameters
    ----------
    frames : ndarray of shape (T, H, W) or FrameSource
        Anything with ``len()``, ``.shape`` and slicing ``frames[a:b]`` -> (b - a, H, W).
    factor : int
        Pixels per block side, >= 1.

    Examples
    --------
    >>> import numpy as np
    >>> b = Binned(np.arange(2 * 4 * 6, dtype=np.uint8).reshape(2, 4, 6), 2)
    >>> b.shape, b[0:1][0, 0].tolist()
    ((2, 2, 3), [3.5, 5.5, 7.5])
    """

    def __init__(self, frames, factor: int):
        self.factor = check_bin(factor)
        n, h, w = (int(v) for v in frames.shape)
        super().__init__(frames, (n, h // self.factor, w // self.factor), np.float32)

    def _read(self, start: int, stop: int) -> np.ndarray:
        raw = self._raw(start, stop)
        _, h, w = self.shape
        f = self.factor
        out = np.empty((len(raw), h, w), np.float32)
        for frame, block in zip(raw, out):          # a loop over frames (OpenCV per frame)
            cv2.resize(frame[:h * f, :w * f].astype(np.float32, copy=False), (w, h),
                       dst=block, interpolation=cv2.INTER_AREA)
        return out


def sequence_floor(frames, smooth: float) -> float:
    """``irdetect.verify.quantisation_floor`` of a sequence's first frame; of the input's
    first frame divided by the factor when ``frames`` is :class:`Binned` (the mean of a
    block of f x f whole grey levels holds their quantisation error divided by f).
    ``frames``: (T, H, W) with T >= 1, anything :class:`Binned` takes, or a Binned."""
    if isinstance(frames, Binned):
        return quantisation_floor(frames.frames[0:1][0], smooth) / frames.factor
    return quantisation_floor(frames[0:1][0], smooth)


def binned_mask(mask: np.ndarray | None, factor: int) -> np.ndarray | None:
    """An (H, W) bool mask of the input's pixels -> (H // factor, W // factor): a block is
    True when any of its pixels is (an excluded pixel excludes its block)."""
    if mask is None or factor == 1:
        return mask
    h, w = mask.shape[0] // factor, mask.shape[1] // factor
    return mask[:h * factor, :w * factor].reshape(h, factor, w, factor).any(axis=(1, 3))


def to_input(name: str, rows: np.ndarray, factor: int) -> np.ndarray:
    """Rows of table ``name`` (``irdetect.tables.BY_NAME``) in binned pixels -> a copy in
    the input's pixels (module notes); rows themselves when ``factor`` is 1."""
    return _scaled(name, rows, factor, inverse=False)


def to_binned(name: str, rows: np.ndarray, factor: int) -> np.ndarray:
    """The inverse of ``to_input``: rows in the input's pixels -> binned pixels."""
    return _scaled(name, rows, factor, inverse=True)


def _scaled(name: str, rows: np.ndarray, factor: int, *, inverse: bool) -> np.ndarray:
    if factor == 1 or not len(rows):
        return rows
    f = float(factor)
    scale, shift = (1 / f, -(f - 1) / 2 / f) if inverse else (f, (f - 1) / 2)
    out = rows.copy()
    for cx, cy in _POSITIONS.get(name, ()):
        out[cx] = scale * out[cx] + shift
        out[cy] = scale * out[cy] + shift
    for col in _LINEAR.get(name, ()):
        out[col] *= scale
    for col in _AREAS.get(name, ()):
        out[col] *= scale * scale
    if name == "tracks":
        # rho = x cos(theta) + y sin(theta): x -> scale x + shift moves it by as much
        out["rho"] = scale * out["rho"] + shift * (np.cos(out["theta"]) + np.sin(out["theta"]))
    return out
