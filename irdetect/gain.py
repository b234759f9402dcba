"""Automatic gain control: each frame's gain and level against frame 0, measured once.

Infrared cameras rescale their output when the scene's range changes (AGC): a frame t
holds g (s - p) + q of the scene s that frame t - 1 held as s. A temporal background
(``irdetect.suppress``) subtracts its past frames unscaled, so after a step every pixel
keeps (g - 1) times its scene for as long as the background spans frames of the old
gain: a 15 % step puts 15 % of every edge and cloud into the residual.

Each frame is compared with the frame before it on their common part, registered by the
camera's offsets rounded to whole pixels (``irdetect.camera``), on about 16,000 pixels of
a regular grid: the gain is the ratio of the two frames' standard deviations there, the
geometric mean of the two least-squares slopes (each alone is biased by noise and
misregistration, the one towards 0, the other away from it), and the map runs through
the two means. Pixels at either frame's extreme value (a clip) and either frame's 1 %
tails are left out, so saturation and a glint do not pull it. A frame's step is taken
only where it departs from 1 by more than ``step`` and by more than four standard errors
of the ratio (``sqrt((1 - r**2) / n)`` in log, r the frames' correlation over n
pixels): the gain of a steady camera moves by at most 2.2 % from frame to frame on the
recorded folders (docs/detection.md), and a step below ``step`` is left to the
background's own drift. The correlation is not required to be high: frames of sparse
structure (hot pixels, a few edges) correlate little and still leave (g - 1) times that
structure after a step (docs/detection.md). Steps compose into the running map (G_t,
O_t) from frame 0's scale to frame t's, raw = G_t x + O_t; ``normalise`` takes a frame
back.
"""

from __future__ import annotations

import numpy as np

#: the fraction by which a frame's gain must depart from 1 against the frame before it to
#: be taken as a step of the camera's gain control (``SuppressConfig.gain_step``)
STEP = 0.05
#: frames are compared on about this many pixels (every k-th pixel of every k-th row):
#: the ratio's standard error is then under 0.8 %
SAMPLES = 16384
#: the fraction of pixels left out at each end of either frame's range
TAIL = 0.01


def frame_gain(previous: np.ndarray, frame: np.ndarray, shift=(0, 0)) -> tuple:
    """The gain and levels of ``frame`` against ``previous`` on their common part.

    Parameters
    ----------
    previous, frame : ndarray of shape (H, W)
        Two frames, any real dtype.
    shift : (float, float)
        (dx, dy) px: a scene point at p in ``previous`` is at p + shift in ``frame``
        (the difference of their ``irdetect.camera`` offsets); rounded to whole pixels.

    Returns
    -------
    gain : float
        sigma_F / sigma_P over the pixels compared (1.0 when too few or flat).
    mean_previous, mean_frame : float
        Their means there: frame ~ gain (previous - mean_previous) + mean_frame.
    correlation : float
        The correlation of the pixels compared (their texture; 0 for pure noise).
    n : int
        The number of pixels compared.
    """
    h, w = previous.shape
    dx, dy = (int(round(float(v))) for v in shift)
    if abs(dx) >= w - 2 or abs(dy) >= h - 2:
        return 1.0, 0.0, 0.0, 0.0, 0
    # frame[y, x] shows what previous[y - dy, x - dx] showed
    fy, fx = slice(max(dy, 0), h + min(dy, 0)), slice(max(dx, 0), w + min(dx, 0))
    py, px = slice(max(-dy, 0), h + min(-dy, 0)), slice(max(-dx, 0), w + min(-dx, 0))
    k = max(1, round(np.sqrt((h - abs(dy)) * (w - abs(dx)) / SAMPLES)))
    p = np.asarray(previous[py, px][::k, ::k], np.float32).ravel()
    f = np.asarray(frame[fy, fx][::k, ::k], np.float32).ravel()
    keep = np.isfinite(p) & np.isfinite(f)
    p, f = p[keep], f[keep]
    if p.size < 16:
        return 1.0, 0.0, 0.0, 0.0, int(p.size)
    keep = np.ones(p.size, bool)
    for v in (p, f):
        lo, hi = np.quantile(v, [TAIL, 1.0 - TAIL])
        keep &= (v >= lo) & (v <= hi) & (v > v.min()) & (v < v.max())
    p, f = p[keep], f[keep]
    n = int(p.size)
    if n < 16:
        return 1.0, 0.0, 0.0, 0.0, n
    mp, mf = float(p.mean(dtype=np.float64)), float(f.mean(dtype=np.float64))
    p, f = (p - mp).astype(np.float64), (f - mf).astype(np.float64)
    sp, sf = float(np.sqrt(p @ p / n)), float(np.sqrt(f @ f / n))
    if sp <= 0.0 or sf <= 0.0:
        return 1.0, mp, mf, 0.0, n
    return sf / sp, mp, mf, float(p @ f / n / (sp * sf)), n


class SensorGain:
    """Streaming estimate of the camera's gain control, frame by frame in order.

    Parameters
    ----------
    step : float
        A frame's gain against the one before it is taken as a step where it departs from
        1 by more than this fraction (and by four standard errors); 0 or less: never.

    Examples
    --------
    >>> import numpy as np, cv2
    >>> rng = np.random.default_rng(0)
    >>> scene = 100 + 20 * cv2.GaussianBlur(rng.normal(size=(64, 64)), (0, 0), 2)
    >>> frames = np.stack([scene, scene, 1.2 * (scene - 100) + 100, 1.2 * (scene - 100) + 100])
    >>> np.round(SensorGain().update(frames, np.zeros((4, 2)))[:, 0], 2).tolist()
    [1.0, 1.0, 1.2, 1.2]
    """

    def __init__(self, step: float = STEP):
        self.step = float(step)
        self.gain, self.level = 1.0, 0.0
        self.previous = None          # the last frame given and its offset
        self.offset = np.zeros(2)
        self.count = 0                # frames given
        self.steps = []               # (frame, gain against the frame before) of each step

    def update(self, frames, offsets) -> np.ndarray:
        """(G_t, O_t) of shape (n, 2) for the next ``frames`` (n, H, W) with their camera
        ``offsets`` (n, 2): raw = G_t x + O_t, x on frame 0's scale."""
        out = np.empty((len(frames), 2))
        for i, frame in enumerate(frames):
            if self.previous is not None and self.step > 0:
                g, mp, mf, r, n = frame_gain(self.previous, frame, offsets[i] - self.offset)
                change = abs(np.log(g))
                error = np.sqrt(max(1.0 - r * r, 0.0) / max(n, 1))
                if change > np.log1p(self.step) and change > 4.0 * error:
                    # frame = g (previous - mp) + mf and previous = G x + O
                    self.level = g * (self.level - mp) + mf
                    self.gain *= g
                    self.steps.append((self.count + i, g))
            out[i] = self.gain, self.level
            self.previous, self.offset = frame, np.asarray(offsets[i], float)
        if len(frames):
            self.previous = np.array(frames[-1])   # the caller's buffer is reused
        self.count += len(frames)
        return out

    def summary(self, shown: int = 5) -> str | None:
        """One line on the steps taken (None when there was none)."""
        if not self.steps:
            return None
        listed = ", ".join(f"frame {t} x{g:.2f}" for t, g in self.steps[:shown])
        more = f" and {len(self.steps) - shown} more" if len(self.steps) > shown else ""
        return (f"the camera's gain control stepped {len(self.steps)} "
                f"time{'s' if len(self.steps) > 1 else ''} ({listed}{more}): those frames "
                f"were taken back to frame 0's gain (suppress.gain_step)")


def normalise(frames: np.ndarray, gains: np.ndarray, limits=None) -> np.ndarray:
    """Frames (n, H, W) taken to frame 0's gain and level: (raw - O_t) / G_t, float32.

    Parameters
    ----------
    frames : ndarray of shape (n, H, W)
        Raw frames, any real dtype.
    gains : ndarray of shape (n, 2)
        (G_t, O_t) of each frame (``SensorGain.update``).
    limits : (float, float) or None
        The raw values the sensor clips at (an integer dtype's range). A pixel at a limit
        is known only as a bound, and the bound moves with the gain: a bright edge
        saturated after a step up reads lower, taken back, than in the frames before it,
        and a background of those frames leaves it as a positive residual. The frames
        are then clipped to the range on which they agree: from max_t (lo - O_t) / G_t
        over the frames t that hold a pixel at ``lo`` to min_t (hi - O_t) / G_t over
        those that hold one at ``hi``. A frame with no pixel at a limit shows every value
        as it is and bounds nothing: clipping at its bound as well took a bright target
        of easy3 (recorded gain steps to x0.59) down to the clouds beside it, under a
        pan, where no frame before the steps had a pixel at 255.
    """
    g = gains[:, 0].astype(np.float32)[:, None, None]
    o = gains[:, 1].astype(np.float32)[:, None, None]
    raw = np.asarray(frames)
    out = (raw.astype(np.float32) - o) / g
    if limits is not None:
        lo, hi = limits
        low, high = ((lo - o) / g).ravel(), ((hi - o) / g).ravel()
        at_lo = (raw == lo).any(axis=(1, 2))
        at_hi = (raw == hi).any(axis=(1, 2))
        np.clip(out, low[at_lo].max() if at_lo.any() else -np.inf,
                high[at_hi].min() if at_hi.any() else np.inf, out=out)
    return out
