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
estimate. Featureless frames give no estimate: the camera is then taken to hold still. A
lone straight edge (a horizon over featureless sky or sea, ``lone_edge``) gives the motion
across it alone, by matching the frame's profile across the edge to the keyframe's
(``_Profile``); along it the camera is taken to hold still (nothing there says how far it
moved, and a background registered on that edge alone does not need it). ``scipy.fft``
(one thread) keeps the offsets the same from run to run.
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
        scaled to at most 1, Hanning window."""
        a = _robust_range(cv2.medianBlur(np.ascontiguousarray(a, np.float32), 3))
        a = a - np.float32(a.mean(dtype=np.float64))
        # at most 1 in magnitude: the cross power's square (``shift``) stays within
        # float32 whatever the frames' grey-level scale (values near 1e9 overflowed it)
        a *= np.float32(1.0 / max(float(np.abs(a).max()), 1e-30))
        return scipy.fft.rfft2(a * self.window)

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


def _noise_spread(a: np.ndarray) -> float:
    """The robust spread of the frame's 3x3 high-pass (frame - its 3x3 median, every 2nd
    pixel): its pixel noise, whatever structure it holds."""
    return _median_spread((a - cv2.medianBlur(a, 3))[::2, ::2])[1]


def textured(frame: np.ndarray) -> bool:
    """Whether ``frame`` (H, W) has structure beyond pixel noise to register on."""
    a = np.asarray(frame, np.float32)
    return _median_spread(a[::2, ::2])[1] > TEXTURE * max(_noise_spread(a), 1e-12)


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
    ``textured`` whether it has anything to register on (``textured``); ``profile`` its
    profile across a lone straight edge (``_Profile``; None unless ``lone_edge`` finds
    one).
    """

    offset: np.ndarray
    spectrum: np.ndarray
    box: tuple | None = None
    crop: "_Gradients | None" = None
    reduced: "_Gradients | None" = None
    textured: bool = True
    profile: "_Profile | None" = None


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
            # a featureless keyframe: only a textured frame (or a lone edge) can become
            # the next one
            if not (textured(reduced) or lone_edge(reduced, self.levels) is not None):
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
            elif self.previous is not None and self.key.profile is None:
                # a weak match against the keyframe (too little overlap left, a blurred
                # jump): one coarse step from the previous frame, and this frame is the
                # next keyframe; when that fails too (a featureless frame) nothing moves.
                # Not after a lone edge's keyframe: phase correlation's peak lies anywhere
                # along the edge (the offset is held, and this frame is the next keyframe)
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
        normal = lone_edge(reduced, self.levels)
        if normal is not None:
            # only the shift across the edge can be measured (``textured`` may not see it:
            # with most of the frame on one side the frame's spread is its noise's)
            return _Reference(self.last.copy(), small, profile=_Profile(reduced, normal))
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
        the full-resolution crop's (when ``frame`` is given and the keyframe has one). A
        keyframe of a lone straight edge is matched across the edge alone (``_Profile``)."""
        if ref.profile is not None:
            n = ref.profile.shift(reduced, (self.limit + EDGE_STEP) / self.scale)
            return None if n is None else n * ref.profile.normal * self.scale
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
    def _band(a, clip: bool = True) -> np.ndarray:
        """The frame median-filtered (3x3: no hot pixels), clipped (``_robust_range``,
        unless ``clip`` is False) and smoothed by 1 px minus its level at ``DETREND`` px:
        the structure that moves with the scene, without the sensor's vignetting or a sky
        gradient that stay put in the image (they would hold the fit at zero shift)."""
        a = cv2.medianBlur(np.ascontiguousarray(a, np.float32), 3)
        if clip:
            a = _robust_range(a)
        return (cv2.GaussianBlur(a, (0, 0), 1.0)
                - cv2.GaussianBlur(a, (0, 0), DETREND, borderType=cv2.BORDER_REFLECT))

    def __init__(self, ref: np.ndarray, clip: bool = True):
        self.ref = self._band(ref, clip)
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


#: the white-noise gain of ``_Gradients``: E[gx^2] per squared spread of the reduced
#: frame's 3x3 high-pass (``_noise_spread``), by the
#: number of ``cv2.pyrDown`` steps (the noise of a reduced frame is correlated); the mean
#: over 4 white-noise frames of 512 px reduced (tests/test_camera.py recomputes them within
#: 10 %); 3 and more: the last
GRADIENT_GAIN = (0.0153, 0.062, 0.086, 0.094)
#: a lone straight edge (``lone_edge``): the structure tensor's larger eigenvalue, less the
#: noise's share, at least EDGE_MAJOR x that share and 4 x the smaller (frames of noise, hot
#: pixels and targets reach 2.4, but not the other two tests), and the smaller, less the
#: noise's share, under EDGE_MINOR x it (simulated horizons over noise: -0.1 to 1.3; every
#: frame of the 17 real folders: 10 and more; textured clouds 6.5 and more; scratch
#: measurements on bench_unseen's 100 scenes, 2026-12-05)
EDGE_MAJOR = 0.5
EDGE_MINOR = 2.0
#: ... and it runs across the frame: of EDGE_PARTS equal parts along it, each holds at
#: least half the mean part's gradient energy across it
EDGE_PARTS = 4
#: px (full resolution): the largest camera step between frames that a lone edge's
#: keyframe is searched for beyond the keyframe's own limit
EDGE_STEP = 16.0
#: the normalised correlation of two edge profiles' derivatives below which they are not
#: taken to match
EDGE_MATCH = 0.5


def lone_edge(frame: np.ndarray, levels: int) -> np.ndarray | None:
    """The unit normal (x, y) of a lone straight edge in a reduced frame, or None.

    A horizon over featureless sky or sea pins the camera's motion across it and leaves
    the motion along it free: phase correlation's peak then lies anywhere along a ridge,
    and over noise the Lucas-Kanade fit's aperture test passes on the noise's gradients
    and fits them (unseen scenes under a pan drifted tens of px along their horizon). The
    frame is such an edge when its gradients' structure tensor, less what white noise of
    the frame's level gives it (``GRADIENT_GAIN``), is strong on one axis and at the noise
    on the other (``EDGE_MINOR``). The frame is not clipped for it (``_Gradients``
    clips it to its median +- 3 robust sigmas, which cut a horizon with most of the
    frame on one side down to its noise).

    Parameters
    ----------
    frame : ndarray of shape (h, w)
        The reduced frame (``levels`` x ``cv2.pyrDown``).
    levels : int
        How many times it was reduced.
    """
    a = np.asarray(frame, np.float32)
    grad = _Gradients(a, clip=False)
    gx, gy = grad.gx.ravel().astype(np.float64), grad.gy.ravel().astype(np.float64)
    noise = len(gx) * GRADIENT_GAIN[min(levels, len(GRADIENT_GAIN) - 1)] * _noise_spread(a) ** 2
    if not noise > 0:
        return None
    sxx, syy, sxy = float(np.dot(gx, gx)), float(np.dot(gy, gy)), float(np.dot(gx, gy))
    half, gap = 0.5 * (sxx + syy), math.sqrt(0.25 * (sxx - syy) ** 2 + sxy * sxy)
    major, minor = (half + gap) / noise - 1.0, (half - gap) / noise - 1.0
    if not (major >= EDGE_MAJOR and minor < min(EDGE_MINOR, 0.25 * major)):
        return None
    angle = 0.5 * math.atan2(2.0 * sxy, sxx - syy)
    normal = np.array([math.cos(angle), math.sin(angle)])
    # across the frame: the gradient energy across it (above the noise's) is spread along
    # the edge, not a short bright bar or streak moving over noise
    h, w = a.shape
    yy, xx = np.mgrid[:h, :w]
    along = (xx * -normal[1] + yy * normal[0]).ravel()
    energy = (gx * normal[0] + gy * normal[1]) ** 2 - noise / len(gx)
    part = np.minimum(((along - along.min()) / (np.ptp(along) + 1e-9) * EDGE_PARTS).astype(int),
                      EDGE_PARTS - 1)
    share = np.bincount(part, energy, EDGE_PARTS)
    if not share.min() >= 0.5 * share.mean():
        return None
    return normal


class _Profile:
    """A reduced keyframe's profile across a lone straight edge, and the shift of a frame
    across that edge (``lone_edge``).

    Pixels are binned by their distance s = n . (x, y) across the edge (n its unit normal)
    and averaged: frame and keyframe give two 1-D profiles whose shift is the camera's
    motion across the edge. Along the edge the camera is taken to hold still, which
    changes nothing for a background registered on that edge alone (it is the same all
    along itself). The profiles' derivatives are correlated (a level or a smooth gradient
    that stays put in the image does not pin the match), then the shift is refined by a
    1-D Lucas-Kanade fit of the profiles. Not clipped as for phase correlation: the clip's
    range follows the share of the frame either side of the edge, and a compact bright
    thing is diluted by a bin's dozens of pixels anyway.
    """

    STEPS = 3

    def __init__(self, frame: np.ndarray, normal: np.ndarray):
        h, w = frame.shape
        self.normal = np.asarray(normal, float)
        yy, xx = np.mgrid[:h, :w]
        s = xx * self.normal[0] + yy * self.normal[1]
        self.index = np.floor(s - s.min()).astype(np.int64).ravel()
        self.bins = int(self.index.max()) + 1
        counts = np.bincount(self.index, minlength=self.bins).astype(float)
        # the bins at the frame's corners hold a few pixels: left out
        self.valid = counts >= 0.25 * counts.max()
        self.counts = np.maximum(counts, 1.0)
        self.ref = self.profile(frame)

    def profile(self, frame: np.ndarray) -> np.ndarray:
        """The mean of the frame (3x3 median) in each bin across the edge, NaN outside
        the valid bins."""
        a = cv2.medianBlur(np.ascontiguousarray(frame, np.float32), 3)
        p = np.bincount(self.index, a.ravel().astype(np.float64), self.bins) / self.counts
        p[~self.valid] = np.nan
        return p

    def shift(self, frame: np.ndarray, reach: float) -> float | None:
        """The shift d (reduced px) of ``frame`` across the edge (a scene point at p in the
        keyframe is at p + d n in the frame), at most ``reach``; None when the profiles do
        not match."""
        cur = self.profile(frame)
        g_ref, g_cur = np.diff(self.ref), np.diff(cur)
        n = len(g_ref)
        reach = int(min(np.ceil(reach), n // 3))
        if reach < 1:
            return None
        lags = np.arange(-reach, reach + 1)
        score = np.full(len(lags), -np.inf)
        for i, lag in enumerate(lags):          # a loop over the lags (tens)
            a = g_ref[max(0, -lag):n - max(0, lag)]
            b = g_cur[max(0, lag):n - max(0, -lag)]
            ok = np.isfinite(a) & np.isfinite(b)
            a, b = a[ok], b[ok]
            norm = math.sqrt(float(np.dot(a, a)) * float(np.dot(b, b)))
            if len(a) >= n // 2 and norm > 0:
                score[i] = float(np.dot(a, b)) / norm
        k = int(np.argmax(score))
        if not score[k] >= EDGE_MATCH:
            return None
        d = float(lags[k])
        if 0 < k < len(lags) - 1 and np.isfinite(score[k - 1]) and np.isfinite(score[k + 1]):
            d += _peak_offset(score[k - 1], score[k], score[k + 1])
        # 1-D Lucas-Kanade with the frame's gain and level against the keyframe's (the
        # camera's gain control): cur(s + d) ~ a ref(s) + b  =>  e = cur(s + d) - ref(s)
        # ~ -r ref'(s) + (a - 1) ref(s) + b, least squares for (r, a - 1, b)
        s = np.arange(self.bins, dtype=float)
        slope = np.gradient(self.ref)
        good = np.isfinite(cur)
        for _ in range(self.STEPS):
            e = np.interp(s + d, s[good], cur[good], left=np.nan, right=np.nan) - self.ref
            ok = np.isfinite(e) & np.isfinite(slope)
            if not float(np.dot(slope[ok], slope[ok])) > 0:
                break
            basis = np.stack([-slope[ok], self.ref[ok] - self.ref[ok].mean(),
                              np.ones(int(ok.sum()))], axis=1)
            r = float(np.linalg.lstsq(basis, e[ok], rcond=None)[0][0])
            if abs(r) > 1.0:                    # the correlation is good to a bin
                break
            d += r
            if abs(r) < 0.01:
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
