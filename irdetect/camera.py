"""Camera motion: the global image shift of every frame, measured once per sequence.

A scene point at image position p in frame 0 lies at p + C_t in frame t (x = column,
y = row, px): ``C`` of shape (T, 2) is the camera's image motion, translation only. It is
what the registered background, the scene-coordinate detection of fast targets and the
track initiation share, and what ``/camera`` in a results file holds.

Each frame is matched against a keyframe: phase correlation on the frames reduced to
64-127 px finds the shift, a Lucas-Kanade fit of the reduced frames refines it, and for
frames reduced twice or more a second fit on a full-resolution crop of at most
``CROP_PX`` px (the keyframe's most textured square) refines it again. The keyframe
moves on when the shift against it passes (min(H, W) - crop) / 8 px or the match is weak,
so errors add up only at keyframe changes, not frame by frame (chained frame-to-frame
estimates drift: phase correlation's sub-pixel estimate is biased towards whole pixels,
docs/real.md). Frames are median-filtered (3x3) and clipped to +-3 robust sigmas first,
and the cross-power spectrum is weighted by a Gaussian low-pass: the sensor's fixed
pattern (hot pixels, a column mesh: flat spectra that stay put in the image), vignetting
(band-passed away for the fit) and the targets themselves do not pin or drag the
estimate. Featureless frames and a lone straight edge give no estimate: the camera is
then taken to hold still. ``scipy.fft`` (one thread) keeps the offsets the same from run
to run.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import cv2
import numpy as np
import scipy.fft

#: frames are reduced (``cv2.pyrDown``, at least once when they are 2 x WORK_PX px or
#: more) until their shorter side is under 2 x WORK_PX
WORK_PX = 64
#: side of the full-resolution crop the shift is refined on (at most half the frame's
#: shorter side)
CROP_PX = 128
#: a block whose offsets stay within this many px is a still camera (``update``)
STILL_STEP = 0.25
#: matches whose peak stands less than this many standard deviations above the
#: correlation surface are not trusted (featureless frames, a blurred jump, a straight
#: horizon over noise whose ridge has no place along it: 5.5-7.8; textured scenes 12-25):
#: the frame keeps the previous frame's offset and the keyframe stays
MIN_PEAK = 10.0
#: the smooth level (Gaussian of this sigma in px) removed from a frame before the
#: Lucas-Kanade refinement (``_Gradients``)
DETREND = 8.0
#: the cross-power spectrum's weight: a Gaussian low-pass of this sigma in cycles per px
LOWPASS = 0.1


class _Correlator:
    """Phase correlation on frames of one shape, reference spectrum cached.

    ``scipy.fft`` (pocketfft on one thread) rather than ``cv2.dft``: OpenCV's threaded DFT
    gave results that differed in the 7th digit from run to run, and the offsets must
    not depend on the run.
    """

    def __init__(self, shape):
        h, w = shape
        self.shape = (h, w)
        self.window = cv2.createHanningWindow((w, h), cv2.CV_32F)
        fy = np.fft.fftfreq(h).astype(np.float32)[:, None]
        fx = np.fft.rfftfreq(w).astype(np.float32)[None, :]
        f2 = fx ** 2 + fy ** 2
        self.lowpass = np.exp(-f2 / (2 * LOWPASS ** 2)).astype(np.float32)
        # the band whose cross power stands for the noise: above 0.35 cycles/px
        self.high = f2 > 0.35 ** 2

    def spectrum(self, a: np.ndarray) -> np.ndarray:
        """Spectrum of a frame (h, w) after a 3x3 median (a hot pixel or any other
        single-pixel spike of the sensor is no structure to register on), mean removed,
        Hanning window."""
        a = _robust_range(cv2.medianBlur(np.ascontiguousarray(a, np.float32), 3))
        a = (a - np.float32(a.mean(dtype=np.float64))) * self.window
        return scipy.fft.rfft2(a)

    def shift(self, ref: np.ndarray, cur: np.ndarray) -> tuple[np.ndarray, float]:
        """(d, peak): frame ``cur`` ~ frame ``ref`` moved by d = (dx, dy) px; ``peak`` the
        correlation peak in standard deviations of the surface (spectra from
        ``spectrum``)."""
        x = cur * np.conj(ref)
        mag = np.abs(x)
        # phase correlation where the frames share signal, less weight where the cross
        # power is at the level of the noise (its median over the highest frequencies):
        # x |x| / (|x|^2 + n^2), by the low-pass
        noise = float(np.median(mag[self.high])) if self.high.any() else 0.0
        weight = mag * mag
        weight += np.float32(noise * noise + 1e-30)
        np.divide(mag, weight, out=weight)
        weight *= self.lowpass
        x *= weight
        r = scipy.fft.irfft2(x, s=self.shape)
        h, w = r.shape
        py, px = np.unravel_index(int(np.argmax(r)), r.shape)
        top = float(r[py, px])
        mean, std = float(r.mean()), float(r.std())
        dx = _peak_offset(r[py, (px - 1) % w], top, r[py, (px + 1) % w])
        dy = _peak_offset(r[(py - 1) % h, px], top, r[(py + 1) % h, px])
        # the peak's index wraps: shifts beyond half the size are negative
        sx = px + dx - (w if px > w // 2 else 0)
        sy = py + dy - (h if py > h // 2 else 0)
        return np.array([sx, sy]), (top - mean) / max(std, 1e-20)


#: frames are clipped to their median +- RANGE robust sigmas before matching: compact
#: bright things (the targets themselves, glints) must not be what the camera's motion
#: is measured on (two bright targets over a featureless sky dragged the estimate along
#: with them)
RANGE = 3.0


#: the Lucas-Kanade fit needs the smaller eigenvalue of the gradients' structure tensor
#: to be at least APERTURE x the larger one: a straight edge alone (a horizon over noise)
#: does not say how far the scene moved along it
APERTURE = 0.02
#: a frame whose (reduced) robust spread is under TEXTURE times that of its 3x3 high-pass
#: has nothing to register on (white noise: 1.6; clouds 10 grey levels peak to peak under
#: noise of sigma 4: 2.8; real scenes 14-360; 1.9 leaves faint clouds in): the camera is
#: taken to hold still rather than to follow whatever few bright things there are (the
#: targets)
TEXTURE = 1.9


def _median_spread(v: np.ndarray) -> tuple[float, float]:
    """Median and 1.4826 MAD of the samples ``v`` (0 when more than half are equal)."""
    med = float(np.median(v))
    return med, 1.4826 * float(np.median(np.abs(v - med)))


def textured(frame: np.ndarray) -> bool:
    """Whether ``frame`` (H, W) has structure beyond pixel noise to register on."""
    a = np.asarray(frame, np.float32)
    hp = a - cv2.medianBlur(a, 3)
    return (_median_spread(a[::2, ::2])[1]
            > TEXTURE * max(_median_spread(hp[::2, ::2])[1], 1e-12))


def _robust_range(a: np.ndarray) -> np.ndarray:
    """``a`` clipped to median +- RANGE x 1.4826 MAD (of every 4th pixel)."""
    med, spread = _median_spread(a[::4, ::4])
    if not spread > 0:
        return a
    return np.clip(a, med - RANGE * spread, med + RANGE * spread)


def _peak_offset(a: float, b: float, c: float) -> float:
    """Sub-pixel offset of a peak b between neighbours a and c: a Gaussian through the 3
    values (a parabola through their logarithms), a parabola when one is not positive."""
    a, b, c = float(a), float(b), float(c)
    if a > 0 and b > 0 and c > 0:
        la, lc = math.log(a), math.log(c)
        d = la - 2 * math.log(b) + lc
    else:
        la, lc, d = a, c, a - 2 * b + c
    if d >= 0:
        return 0.0
    return min(0.5, max(-0.5, 0.5 * (la - lc) / d))


def _reduce(frame: np.ndarray, levels: int) -> np.ndarray:
    """``levels`` x ``cv2.pyrDown``, in float32 (an 8-bit frame reduced as 8 bits keeps a
    dozen grey levels of its noise: too few to measure it or to register sub-pixel)."""
    out = np.asarray(frame, np.float32)
    for _ in range(levels):
        out = cv2.pyrDown(out)
    return out


class _Reference(NamedTuple):
    """What a frame is matched against: a keyframe, or the previous frame (spectrum only).

    ``offset`` (2,) its camera offset; ``spectrum`` of its reduced frame; ``box`` (x, y)
    of its full-resolution crop and ``crop`` that crop's ``_Gradients`` (None when the
    frame is not reduced twice or more); ``reduced`` its reduced frame's ``_Gradients``;
    ``textured`` whether it has anything to register on (``textured``).
    """

    offset: np.ndarray
    spectrum: np.ndarray
    box: tuple | None = None
    crop: "_Gradients | None" = None
    reduced: "_Gradients | None" = None
    textured: bool = True


class CameraMotion:
    """Streaming estimate of the camera's image motion, frame by frame in order.

    Parameters
    ----------
    shape : (int, int)
        Frame (H, W).

    Examples
    --------
    >>> import numpy as np, cv2
    >>> rng = np.random.default_rng(0)
    >>> scene = cv2.GaussianBlur(rng.normal(size=(300, 300)).astype(np.float32), (0, 0), 3)
    >>> frames = np.stack([scene[10 + t:210 + t, 20:220] for t in range(5)])
    >>> c = CameraMotion(frames.shape[1:]).update(frames)   # the scene moves up 1 px/frame
    >>> np.round(c[:, 1], 1).tolist()
    [0.0, -1.0, -2.0, -3.0, -4.0]
    """

    def __init__(self, shape):
        h, w = (int(v) for v in shape)
        self.shape = (h, w)
        self.levels = 0
        while min(h, w) >> (self.levels + 1) >= WORK_PX:
            self.levels += 1
        small = _reduce(np.zeros((h, w), np.float32), self.levels).shape
        self.scale = 2.0 ** self.levels
        self.coarse = _Correlator(small) if min(small) >= 8 else None
        # the crop leaves room for shifts up to the keyframe's limit on either side; frames
        # reduced once or not at all are refined on their reduced frame alone (0.05-0.1
        # px there)
        side = min(CROP_PX, min(h, w) // 2)
        self.fine = self.levels > 1 and side >= 16
        self.side = side
        # px: the keyframe moves on beyond (the refinement's crop stays inside: the crop
        # is chosen at least (H - side) / 4 px from the borders)
        self.limit = max(2.0, (min(h, w) - side) / 8.0)
        self.key = None                        # the keyframe (``_Reference``)
        self.previous = None                   # the last frame (``_Reference``, spectrum only)
        self.last = np.zeros(2)
        self.still = False                     # the last block's offsets did not move
        self.matched = False                   # ... and some of its frames matched

    def update(self, frames) -> np.ndarray:
        """Offsets C_t (n, 2) = (dx, dy) of the next ``frames`` (n, H, W), relative to the
        first frame ever given (a scene point at p in that frame is at p + C_t).

        While the camera holds still (the last block's offsets within ``STILL_STEP`` px
        of each other), a block's last frame is matched first; when it too is within
        ``STILL_STEP`` of the last offset the block's frames all keep that offset (one
        match for the block instead of one per frame)."""
        n = len(frames)
        if self.still and n > 2 and self.key is not None:
            probe = self._probe(frames[-1])
            # a weak match on frames that gave none before either (featureless: noise,
            # flat sky) says as little as matching every frame would
            if (probe is None and not self.matched) or (
                    probe is not None and np.abs(probe - self.last).max() < STILL_STEP):
                return np.repeat(self.last[None], n, axis=0)
        out = np.zeros((n, 2))
        self.matched = False
        for i, frame in enumerate(frames):
            out[i] = self._one(frame)
        self.still = bool(np.ptp(out, axis=0).max() < STILL_STEP) if n else self.still
        return out

    def _probe(self, frame):
        """The offset of ``frame`` against the keyframe (None when the match is weak),
        leaving the estimator's state as it was."""
        if self.coarse is None:
            return None
        reduced = _reduce(frame, self.levels)
        if not np.isfinite(reduced).all() or reduced.std() <= 0:
            return None
        d = self._match(self.key, self.coarse.spectrum(reduced), frame, reduced)
        return None if d is None else self.key.offset + d

    def _one(self, frame) -> np.ndarray:
        if self.coarse is None:
            return self.last.copy()
        reduced = _reduce(frame, self.levels)
        if not np.isfinite(reduced).all() or reduced.std() <= 0:
            return self.last.copy()
        if self.key is not None and not self.key.textured:
            # a featureless keyframe: only a textured frame can become the next one
            if not textured(reduced):
                return self.last.copy()
            self.key = None
        small = self.coarse.spectrum(reduced)
        if self.key is not None:
            d = self._match(self.key, small, frame, reduced)
            if d is not None:
                self.matched = True
                self.last = self.key.offset + d
                if np.abs(d).max() > self.limit:
                    self.key = None
            elif self.previous is not None:
                # a weak match against the keyframe (too little overlap left, a blurred
                # jump): one coarse step from the previous frame, and this frame is the
                # next keyframe; when that fails too (a featureless frame) nothing moves
                d = self._match(self.previous, small, None, reduced)
                if d is not None:
                    self.last = self.previous.offset + d
                    self.key = None
        if self.key is None:
            self.key = self._key(frame, small, reduced)
        self.previous = _Reference(self.last.copy(), small)
        return self.last.copy()

    def _key(self, frame, small, reduced) -> _Reference:
        """A new keyframe at this frame (``reduced``: it reduced, ``small``: that one's
        spectrum)."""
        if not textured(reduced):
            return _Reference(self.last.copy(), small, textured=False)
        lk = _Gradients(reduced)
        if not self.fine:
            return _Reference(self.last.copy(), small, reduced=lk)
        f = np.asarray(frame, np.float32)
        x0, y0 = _textured_box(f, self.side)
        crop = _Gradients(f[y0:y0 + self.side, x0:x0 + self.side])
        return _Reference(self.last.copy(), small, (x0, y0), crop, lk)

    def _match(self, ref, small, frame, reduced):
        """Shift of ``frame`` (``reduced``: it reduced, ``small``: that one's spectrum)
        against the reference ``ref``, or None when the match is weak: phase correlation,
        then the reference's Lucas-Kanade fit on the reduced frames (a keyframe's), then
        the full-resolution crop's (when ``frame`` is given and the keyframe has one)."""
        d, peak = self.coarse.shift(ref.spectrum, small)
        if peak < MIN_PEAK or not np.isfinite(d).all():
            return None
        if ref.reduced is not None:
            d = ref.reduced.refine(reduced, d)
            if d is None:
                return None
        d = d * self.scale
        if frame is not None and ref.box is not None:
            d = self._refine(ref, frame, d)
        return d

    def _refine(self, ref, frame, d) -> np.ndarray:
        """The coarse shift d refined at full resolution on the keyframe's crop: the
        frame's crop at the whole-pixel shift, then the rest by ``_Gradients``."""
        (x0, y0), crop = ref.box, ref.crop
        h, w = self.shape
        s = self.side
        ix, iy = int(round(d[0])), int(round(d[1]))
        x1, y1 = x0 + ix, y0 + iy
        if not (0 <= x1 <= w - s and 0 <= y1 <= h - s):
            return d
        part = np.asarray(frame[y1:y1 + s, x1:x1 + s], np.float32)
        # the reduced frame's estimate is good to about a reduced pixel; a crop that
        # cannot say more keeps it
        r = crop.refine(part, np.asarray(d) - (ix, iy), reach=max(2.0, self.scale))
        return d if r is None else np.array([ix, iy]) + r


class _Gradients:
    """Lucas-Kanade refinement of a translation against one reference frame.

    Phase correlation finds the peak; on smooth scenes under noise (clouds: texture and
    noise of the same size per pixel) its position is 1-2 px off, while the
    least-squares fit of the residual to the reference's gradients,
    [sum gx^2, sum gx gy; sum gx gy, sum gy^2] r = -sum (g e), is the efficient
    estimate of a small shift. The reference's band-passed frame and its gradients are
    computed once per keyframe; each step sums them over the pixels the moved-back frame
    covers.
    """

    STEPS = 2

    @staticmethod
    def _band(a) -> np.ndarray:
        """The frame median-filtered (3x3: no hot pixels) and smoothed by 1 px minus its
        level at ``DETREND`` px: the structure that moves with the scene, without the
        sensor's vignetting or a sky gradient that stay put in the image (they would
        hold the fit at zero shift)."""
        a = _robust_range(cv2.medianBlur(np.ascontiguousarray(a, np.float32), 3))
        return (cv2.GaussianBlur(a, (0, 0), 1.0)
                - cv2.GaussianBlur(a, (0, 0), DETREND, borderType=cv2.BORDER_REFLECT))

    def __init__(self, ref: np.ndarray):
        self.ref = self._band(ref)
        self.gx = cv2.Sobel(self.ref, cv2.CV_32F, 1, 0, ksize=3) / 8.0
        self.gy = cv2.Sobel(self.ref, cv2.CV_32F, 0, 1, ksize=3) / 8.0

    def refine(self, frame: np.ndarray, d: np.ndarray, reach: float = 2.0):
        """The shift d (frame ~ reference moved by d) refined; None when the gradients
        do not pin a shift down on both axes (a flat frame, or one straight edge such
        as a horizon: phase correlation's peak then lies anywhere along a ridge) or the
        fit runs more than ``reach`` px from d."""
        h, w = self.ref.shape
        cur = self._band(frame)
        start = np.asarray(d, float)
        d = start.copy()
        for _ in range(self.STEPS):
            back = cv2.warpAffine(cur, np.float32([[1, 0, -d[0]], [0, 1, -d[1]]]), (w, h),
                                  flags=cv2.INTER_LINEAR + cv2.WARP_FILL_OUTLIERS,
                                  borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
            m = int(np.ceil(np.abs(d).max())) + 2
            if 2 * m >= min(h, w):
                return None
            e = (back - self.ref)[m:-m, m:-m]
            gx, gy = self.gx[m:-m, m:-m], self.gy[m:-m, m:-m]
            ok = np.isfinite(e)
            e, gx, gy = e[ok], gx[ok], gy[ok]
            sxx, sxy, syy = float(np.dot(gx, gx)), float(np.dot(gx, gy)), float(np.dot(gy, gy))
            det = sxx * syy - sxy * sxy
            # the gradients must pin both axes down (not one edge, not a flat frame):
            # the structure tensor's smaller eigenvalue against its larger
            half, gap = 0.5 * (sxx + syy), np.sqrt(0.25 * (sxx - syy) ** 2 + sxy * sxy)
            if not half - gap > APERTURE * (half + gap):
                return None
            bx, by = float(np.dot(gx, e)), float(np.dot(gy, e))
            # back(x) = cur(x + d) ~ ref(x) - g r  =>  r = -A^-1 sum(g e)
            r = -np.array([syy * bx - sxy * by, sxx * by - sxy * bx]) / det
            d = d + r
            if np.abs(d - start).max() > reach:
                return None
            if np.abs(r).max() < 0.01:
                break
        return d


def _textured_box(frame: np.ndarray, side: int) -> tuple[int, int]:
    """Top-left (x, y) of the ``side``-px square, on a grid of half steps inside the
    central part of the frame, whose gradients are strongest in both directions: the
    smaller eigenvalue of the summed structure tensor (Shi and Tomasi's criterion over
    the square; a straight edge alone cannot say how far the scene moved along it)."""
    h, w = frame.shape
    gx = cv2.Sobel(frame, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(frame, cv2.CV_32F, 0, 1, ksize=3)
    sums = [cv2.integral(g) for g in (gx * gx, gy * gy, gx * gy)]
    step = max(1, side // 2)
    # keep a margin of a quarter of the free space so the shifted crop stays inside
    ys = np.arange((h - side) // 4, h - side - (h - side) // 4 + 1, step)
    xs = np.arange((w - side) // 4, w - side - (w - side) // 4 + 1, step)
    y, x = np.meshgrid(ys, xs, indexing="ij")
    a, b, c = (i[y + side, x + side] - i[y, x + side] - i[y + side, x] + i[y, x] for i in sums)
    smaller = 0.5 * (a + b) - np.sqrt(0.25 * (a - b) ** 2 + c ** 2)
    k = np.unravel_index(int(np.argmax(smaller)), smaller.shape)
    return int(x[k]), int(y[k])


def estimate_motion(frames) -> np.ndarray:
    """Camera offsets C (T, 2) of a whole sequence (``CameraMotion`` over its frames).

    Parameters
    ----------
    frames : ndarray of shape (T, H, W)

    Returns
    -------
    ndarray of float64 of shape (T, 2)
        (dx, dy) px: a scene point at p in frame 0 is at p + C_t in frame t.
    """
    frames = np.asarray(frames)
    if frames.ndim != 3:
        raise ValueError(f"frames must have shape (T, H, W), got {frames.shape}")
    return CameraMotion(frames.shape[1:]).update(frames)
