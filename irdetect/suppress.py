"""Clutter suppression: remove the background so only point-like residuals remain.

Wan & Askar (2008) only say "clutter suppression as in reference [2]". irdetect offers
four suppressors and picks the default by measurement (``scripts/bench_detection.py``,
``docs/results/detection.md``):

``tophat``
    White morphological top-hat, ``frame - opening(frame)`` with a ``size`` x ``size``
    square; anything narrower than ``size`` survives, broad background goes.
``maxmean`` / ``maxmedian``
    Directional max-mean / max-median background (Deshpande et al. 1999): along the 4
    lines (0, 45, 90, 135 degrees) through the pixel, the mean (median) of the samples
    outside a guard of ``guard`` pixels; the background is the largest of the 4, so an
    edge in any direction is predicted and removed.
``temporal``
    Causal temporal background: the mean of the previous ``history`` frames at the same
    pixel (the first frame of a sequence, with no past, uses the next ``history`` frames,
    or a ``size`` x ``size`` box mean with ``lead_in="tophat"``). Removes still clutter
    of any shape, and also still targets.
``registered``
    Motion-compensated temporal background for a moving camera (beyond the paper): the
    camera's image offset of every frame is measured (``irdetect.camera``), the past
    frames at lags ``gap`` .. ``gap + history - 1`` are shifted onto the current frame
    and averaged, the average is dilated by ``tolerance`` px (so sub-pixel registration
    error on edges leaves no residue) and subtracted. Before that, the sensor's fixed
    pattern (defective pixels, the column/row mesh: structure that stays put in the
    image while the scene moves) is estimated as the temporal median of each frame's
    3x3 high-pass over the available frames and removed. Keeps a target that moves
    relative to the scene by more than about ``tolerance + 2`` px over ``gap`` frames,
    even when the camera holds it still in the image. The first ``gap`` frames of a
    sequence have no past that old: their background is built the same way from the
    frames at the mirrored lags after them (``lead_in="future"``; a streaming caller
    passes them as ``following``) or is a ``size`` top-hat (``lead_in="tophat"``).
``auto``
    ``temporal`` while the camera holds still, ``registered`` when it moves: per call
    (one window when streaming), when the camera's offsets over the frames held
    (``previous`` and ``frames``) move by ``STILL_PX`` px or more (``camera_moves``)
    and the registered background leaves clearly fewer bright residues than the
    image-fixed one (``residue``: clouds drifting over a still ground move the
    offsets too).

All arithmetic is float32 with OpenCV filters; a stack (T, H, W) is processed frame by
frame inside one call (no Python work per pixel).
"""

from __future__ import annotations

import numpy as np
import cv2

from irdetect.camera import estimate_motion
from irdetect.robust import median_mad_sigma, sorted_median, tile_map, tile_samples

METHODS = ("tophat", "maxmean", "maxmedian", "temporal", "registered", "auto", "none")
LEAD_INS = ("future", "tophat")
#: targets brighter than their background (a white-hot recording) or darker (black-hot,
#: or a target colder than what lies behind it)
POLARITIES = ("bright", "dark")


def suppress(frames, previous=None, following=None, camera=None, long_past=None, *,
             method: str = "auto", size: int = 9, guard: int = 1, history: int = 12,
             gap: int = 8, tolerance: int = 1, fixed_pattern: bool = True, samples: int = 3,
             lead_in: str = "future", polarity: str = "bright") -> np.ndarray:
    """Suppress the background of one frame or a stack of frames.

    Parameters
    ----------
    frames : ndarray of shape (H, W) or (T, H, W)
        Raw frames, any real dtype. NaN pixels are replaced by the frame's median of
        the finite pixels (0 when none is finite) before filtering.
    previous : ndarray of shape (P, H, W), optional
        ``temporal`` / ``registered``: raw frames just before ``frames[0]`` (the tail of
        the previous block when streaming); only the last ``past_frames(...)`` are used.
    following : ndarray of shape (N, H, W), optional
        ``temporal`` / ``registered`` with ``lead_in="future"``: raw frames just after
        ``frames[-1]``, read only for the first frames of a sequence (the block needs
        ``future_frames(...)`` of them); they are not suppressed themselves.
    camera : ndarray of shape (P + T + N, 2), optional
        ``registered`` / ``auto``: the camera's image offsets (x, y) px of ``previous``,
        ``frames`` and ``following`` (``irdetect.camera``: a scene point at p in one
        frame is at p + C_j - C_i in another); measured here from those frames when
        not given (the pipeline measures them once per sequence).
    method : {"tophat", "maxmean", "maxmedian", "temporal", "registered", "auto", "none"}
        The suppressor (see the module docstring).
    size : int
        Odd structuring-element / line length in pixels (>= 3). For ``tophat`` it must
        exceed the target size (3 px in the paper's model), for ``maxmean`` /
        ``maxmedian`` it is the full line length through the pixel.
    guard : int
        ``maxmean`` / ``maxmedian``: samples within ``guard`` pixels of the centre are
        left out of the background, so a 3x3 target does not raise its own background.
    history : int
        ``temporal`` / ``registered``: number of past frames averaged into the
        background (>= 1).
    gap : int
        ``registered``: lag in frames of the newest frame in the background (>= 1); the
        target must move relative to the scene by a few px within it.
    tolerance : int
        ``registered``: the background is dilated by a (2 tolerance + 1)-square (>= 0),
        so registration errors up to ``tolerance`` px leave no edge residue.
    fixed_pattern : bool
        ``registered``: remove the sensor's fixed pattern first (see Notes).
    samples : int
        ``registered``: number of past frames, evenly spread over the lags
        [gap, gap + history), averaged into the background (>= 1); each costs one
        phase correlation per frame.
    lead_in : {"future", "tophat"}
        ``temporal`` / ``registered``: the background of the frames with no past (the
        first frame, respectively the first ``gap`` frames, of a sequence): built the
        same way from the frames after them at the mirrored lags (``"future"``, those
        in ``frames`` + ``following``), or a ``size`` top-hat / box mean (``"tophat"``).
    long_past : ndarray of shape (S, H, W), optional
        ``temporal`` (also as ``auto``'s choice): raw frames of a still camera from long
        before ``frames`` (the pipeline passes the first frames of the earlier windows,
        ``ProcessConfig.suppress.long_memory``); a point that arrived and stays keeps
        its residual against their median (see Notes).
    polarity : {"bright", "dark"}
        Targets brighter than their background (``bright``: a white-hot recording) or
        darker (``dark``: black-hot, or a target colder than its background): every
        frame given is mirrored in grey level first (``bright_up``), so a dark target's
        residual is positive as a bright one's is.

    Returns
    -------
    ndarray of float32, the shape of ``frames``
        The residual (frame minus background); signed except for ``tophat``.

    Notes
    -----
    The paper's model is Z(r, k) = S(r, k) + N(r, k) after suppression (its eq. 1); it
    does not say how clutter is suppressed. We offer several and choose by measurement.
    The temporal suppressor is causal (past frames only) so that a streaming pipeline
    needs to keep only ``history`` frames; its running mean costs O(1) per pixel.

    ``registered`` (for a moving camera, measured on the DAUB sequences, docs/real.md):
    background B_t = dilate(mean_l warp(F_{t-l}, d_{t-l,t})) over ``samples`` lags l
    evenly spread in [gap, gap + history) that exist, d = C_t - C_{t-l} the shift of
    frame t against frame t-l from the camera's offsets C (``irdetect.camera``, each
    frame measured against a keyframe: once per frame, not per lag); pixels that no
    shifted past frame covers give residual 0. The first ``gap`` frames
    of a sequence, with no past that old, take frames t+l instead (``lead_in="future"``:
    the same background, looking ahead) or the ``size`` top-hat (``"tophat"``, whose
    clutter is wider than a target but not always: a target on the edge of a bright
    structure wider than ``size`` keeps a plateau around it, daub-data13-a frame 6).
    Translation only (no rotation or parallax; the dilation absorbs up to ``tolerance``
    px of either).
    Long memory (``long_past``, beyond the paper; issue 26): the ``history``-frame mean
    learns a target that stops within ``history`` frames. Against L, the median of the
    ``long_past`` frames, it still stands out: where F - L exceeds ``HOLD_K`` robust
    sigmas of F - L while the residual F - B is under half of it, in 8-connected
    components no wider or taller than ``size`` (point-like, like the top-hat's test),
    dilated by 2 px, the residual is max(F - B, F - L). Structure that was there before
    (in L) and wide changes (a cloud arriving, a gain step) are left to B; a point that
    moves has F - B about F - L and is unchanged. A target that stops stays visible
    until it is in half the ``long_past`` frames.

    Fixed pattern: P = median over the frames (``previous`` and ``frames``) of
    F - medianBlur3(F), subtracted from every frame; a target sits on the same pixel
    in well under half of them (DAUB: at most 46 % of 24 frames) and is not in P.

    Examples
    --------
    >>> import numpy as np
    >>> frame = np.zeros((32, 32), np.float32); frame[:, 16:] = 100; frame[8, 8] = 5
    >>> res = suppress(frame, method="tophat", size=5)
    >>> float(res[8, 8]), float(res[:, 16:].max())
    (5.0, 0.0)
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    if int(size) != size or size < 3 or size % 2 == 0:
        raise ValueError(f"size must be an odd integer >= 3, got {size!r}")
    if int(guard) != guard or guard < 0 or 2 * guard + 1 >= size:
        raise ValueError(f"guard must be an integer with 0 <= 2*guard+1 < size, got {guard!r}")
    if int(history) != history or history < 1:
        raise ValueError(f"history must be an integer >= 1, got {history!r}")
    if int(gap) != gap or gap < 1:
        raise ValueError(f"gap must be an integer >= 1, got {gap!r}")
    if int(tolerance) != tolerance or tolerance < 0:
        raise ValueError(f"tolerance must be an integer >= 0, got {tolerance!r}")
    if int(samples) != samples or samples < 1:
        raise ValueError(f"samples must be an integer >= 1, got {samples!r}")
    if lead_in not in LEAD_INS:
        raise ValueError(f"lead_in must be one of {LEAD_INS}, got {lead_in!r}")
    if is_dark(polarity):
        frames, previous, following, long_past = (
            None if a is None else bright_up(a) for a in (frames, previous, following, long_past))
    arr = np.asarray(frames)
    if arr.ndim not in (2, 3) or arr.shape[-1] == 0 or arr.shape[-2] == 0:
        raise ValueError(f"frames must have shape (H, W) or (T, H, W), got {arr.shape}")
    single = arr.ndim == 2
    stack = _clean(arr[None] if single else arr)
    if method in ("temporal", "registered", "auto"):
        past = None
        keep = past_frames(method, history=history, gap=gap)
        n_given = 0 if previous is None else len(previous)
        if previous is not None:
            past = np.asarray(previous)
            if past.ndim != 3 or past.shape[1:] != stack.shape[1:]:
                raise ValueError(f"previous must have shape (P, {stack.shape[1]}, "
                                 f"{stack.shape[2]}), got {past.shape}")
            past = past[-keep:] if len(past) else None
        future = None
        if following is not None and lead_in == "future":
            future = np.asarray(following)
            if future.ndim != 3 or future.shape[1:] != stack.shape[1:]:
                raise ValueError(f"following must have shape (N, {stack.shape[1]}, "
                                 f"{stack.shape[2]}), got {future.shape}")
            future = _clean(future) if len(future) else None
        n_past = 0 if past is None else len(past)
        n_future = 0 if future is None else len(future)
        if camera is not None:
            cam = np.asarray(camera, np.float64)
            n_follow = 0 if following is None else len(following)
            if cam.shape != (n_given + len(stack) + n_follow, 2):
                raise ValueError(f"camera must have shape ({n_given + len(stack) + n_follow}, 2)"
                                 f" (previous, frames, following), got {cam.shape}")
            cam = cam[n_given - n_past:n_given + len(stack) + n_future]
        elif method != "temporal":
            parts = [a for a in (past, stack, future) if a is not None]
            cam = estimate_motion(parts[0] if len(parts) == 1 else np.concatenate(parts))

        def temporal():
            # integer frames enter the float32 running sum as they are stored (the same
            # values as converted copies, without converting the past once more)
            p = None if past is None else past[-history:]
            p = p if p is None or p.dtype.kind in "biu" else _clean(p)
            out = _temporal(stack, int(history), int(size), p, future, lead_in == "future")
            if long_past is not None and len(long_past) >= HOLD_MIN:
                _keep_arrivals(out, stack, _long_background(long_past, stack.shape[1:]),
                               int(size))
            return out

        def registered():
            return _registered(stack, past, cam,
                               int(history), int(gap), int(tolerance), bool(fixed_pattern),
                               int(samples), int(size), future, lead_in == "future")

        if method == "temporal":
            out = temporal()
        elif method == "registered":
            out = registered()
        elif not camera_moves(cam[:n_past + len(stack)]):
            out = temporal()
        else:
            # the camera's offsets move (they follow the scene's dominant texture, which
            # may be clouds drifting over a still ground): registered only when it leaves
            # clearly fewer bright residues than the image-fixed background
            out, other = registered(), temporal()
            if not prefer_registered(out, other):
                out = other
    elif method == "none":
        out = stack.copy()
    else:
        kernel = {"tophat": _tophat, "maxmean": _maxmean, "maxmedian": _maxmedian}[method]
        out = np.empty_like(stack)
        for t in range(len(stack)):
            out[t] = kernel(stack[t], int(size), int(guard))
    return out[0] if single else out


def is_dark(polarity: str) -> bool:
    """Whether ``polarity`` (one of POLARITIES) asks for the frames mirrored in grey level
    (``bright_up``); ValueError for any other value."""
    if polarity not in POLARITIES:
        raise ValueError(f"polarity must be one of {POLARITIES}, got {polarity!r}")
    return polarity == "dark"


def bright_up(frames) -> np.ndarray:
    """Frames mirrored in grey level, so that dark targets become bright ones.

    Integer frames take the bitwise not (``max - v`` for unsigned types, ``-1 - v`` for
    signed ones): exact, in the same dtype, and its own inverse, so a black-hot recording
    of integer frames gives back the white-hot one value for value. Float frames are
    negated. Any shape; returns a new array.
    """
    a = np.asarray(frames)
    return np.invert(a) if a.dtype.kind in "biu" else np.negative(a)


#: ``auto`` with a moving camera: the registered background is taken when its residual's
#: robust sigma is under WIDER times the image-fixed one's, or its share of bright residue
#: pixels under BRIGHTER times (``residue``)
WIDER = 0.9
BRIGHTER = 0.5
#: ... when the image-fixed one leaves at least this share (fewer is noise: 0-0.2 per
#: mille on the simulator's scenes of a still camera)
BRIGHT_MIN = 5e-4
#: ``residue``'s bright share counted on the window's mean residual (True) or on its
#: frames (False, the design before 2026-12-06, which the tracker's detector keeps):
#: under added sensor noise the frames' share of still structures fell under BRIGHT_MIN
#: on istd640-seq1-101 and its drifting camera got the image-fixed background
#: (docs/real.md, "With added noise")
RESIDUE_ON_MEAN = True


def residue(residual, k: float = 4.0, on_mean: bool | None = None) -> tuple[float, float]:
    """(sigma, share) of a suppressed window (T, H, W): its robust sigma on every 3rd frame
    and 4th pixel (a background that leaks a moving scene spreads wider), and the share
    of bright residue the detection would pick up: the pixels more than ``k`` robust
    sigmas above the median of the window's mean residual on a 2-px grid
    (``on_mean``, default ``RESIDUE_ON_MEAN``), or of those frames and pixels
    (``on_mean`` False). In the mean, the noise falls by the square root of the frames
    while residue that stays put does not, so the share does not vanish as the noise
    grows.

    Measured (share per mille, registered / temporal, the windows whose camera offsets
    move; a scratch measurement of 2026-12-06), on the frames and on the mean: the DAUB
    folders 0.0-9.6 / 11-46 and 0.0-2.9 / 11-53; the istd640 folders 0.0-81 / 1.0-159
    and 0.0-27 / 1.5-142; the simulator's still ground under clouds drifting 0.1
    px/frame (the ``clutter`` preset, 3 seeds; sigmas alike) 0.0-0.2 / 0.0-0.1 and
    0.0-0.1 / 0.0-0.3; istd640-seq1-101 with white noise of 1 grey level added 0.0-0.1 /
    0.3-0.5 and 0.0-0.1 / 0.8-2.4.
    """
    r = np.asarray(residual)
    v = r[::3, ::4, ::4].ravel()
    med, sig = median_mad_sigma(v)
    sig = max(float(sig), 1e-12)
    if on_mean is None:
        on_mean = RESIDUE_ON_MEAN
    if on_mean:
        v = r[:, ::2, ::2].mean(axis=0).ravel()
        med, spread = median_mad_sigma(v)
        spread = max(float(spread), 1e-12)
    else:
        spread = sig
    return sig, float(np.count_nonzero(v - med > k * spread) / max(v.size, 1))


def prefer_registered(registered, temporal, on_mean: bool | None = None) -> bool:
    """``auto``'s choice when the camera's offsets move: whether the registered window
    ``registered`` (T, H, W) leaves clearly less than the image-fixed one ``temporal``
    (T, H, W): a robust sigma under ``WIDER`` times its, or (when the image-fixed one
    leaves at least ``BRIGHT_MIN``) a share of bright residue under ``BRIGHTER`` times
    its (``residue``, ``on_mean``)."""
    (s_reg, b_reg), (s_tem, b_tem) = (residue(registered, on_mean=on_mean),
                                      residue(temporal, on_mean=on_mean))
    return bool(s_reg < WIDER * s_tem or (b_tem >= BRIGHT_MIN and b_reg < BRIGHTER * b_tem))


def past_frames(method: str, *, history: int = 12, gap: int = 8, **_) -> int:
    """Raw frames before a block that ``suppress(method=...)`` uses (``previous``)."""
    if method == "temporal":
        return int(history)
    if method == "registered":
        return int(gap) + int(history) - 1
    if method == "auto":
        return max(int(history), int(gap) + int(history) - 1)
    return 0


def future_frames(method: str, start: int, stop: int, *, history: int = 12, gap: int = 8,
                  lead_in: str = "future", **_) -> int:
    """Raw frames after a block of sequence frames [start, stop) that ``suppress`` uses
    (``following``): the look-ahead of the first frames of a sequence, 0 for the rest."""
    if lead_in != "future" or method not in ("temporal", "registered", "auto"):
        return 0
    # frames before `lead` have no past: temporal's first frame, registered's first `gap`
    lead, reach = int(gap), int(gap) + int(history) - 1
    if method == "temporal":
        lead, reach = 1, int(history)
    if method == "auto":
        reach = max(reach, int(history))
    if start >= lead or stop <= start:
        return 0
    # the last frame without a past, min(stop, lead) - 1, reaches ``reach`` frames ahead
    return max(0, min(stop, lead) + reach - stop)


#: ``auto``: a shift of this many px or more within the frames held means a moving camera
STILL_PX = 0.5


def camera_moves(offsets) -> bool:
    """Whether the camera moves: the last frame held is shifted by ``STILL_PX`` px or more
    (either axis) against the oldest or the middle one.

    ``offsets``: ndarray of shape (T, 2), the camera's image offsets (x, y) px of
    consecutive frames (``irdetect.camera``).
    """
    c = np.asarray(offsets, np.float64).reshape(-1, 2)
    if len(c) < 2:
        return False
    last = c[-1]
    return bool(max(np.abs(last - c[0]).max(), np.abs(last - c[(len(c) - 1) // 2]).max())
                >= STILL_PX)


def noise_sigma(residual, *, tile: int | None = None, sample: int = 2) -> np.ndarray | float:
    """Robust noise standard deviation of a residual: 1.4826 x median absolute deviation.

    Parameters
    ----------
    residual : ndarray of shape (H, W)
        A suppressed frame (or any 2-D map whose noise is wanted).
    tile : int, optional
        When given, estimate per ``tile`` x ``tile`` block and return a map of shape
        (H, W) (bilinear between block centres); otherwise one number for the frame.
    sample : int
        Use every ``sample``-th pixel in each direction (the median is robust enough;
        this keeps the estimate cheap).

    Returns
    -------
    float or ndarray of float32 of shape (H, W)
        Never zero for a frame with any variation: when the MAD is 0 (more than half
        the pixels equal, e.g. a flat or quantised frame) the mean absolute deviation
        x 1.2533 is used instead, and a constant frame gives the smallest positive float32.

    Notes
    -----
    The MAD ignores up to half the pixels being targets or clutter residue, so a bright
    target cannot raise its own threshold (the paper's fixed threshold would not adapt
    to the noise at all; we make it CFAR-style, see ``irdetect.detect``).
    """
    r = np.asarray(residual, dtype=np.float32)
    if r.ndim != 2:
        raise ValueError(f"residual must have shape (H, W), got {r.shape}")
    if int(sample) != sample or sample < 1:
        raise ValueError(f"sample must be an integer >= 1, got {sample!r}")
    if tile is None:
        return _robust_sigma(r[::sample, ::sample].ravel())
    if int(tile) != tile or tile < 4:
        raise ValueError(f"tile must be an integer >= 4, got {tile!r}")
    return _sigma_map(r, int(tile))


# --- kernels --------------------------------------------------------------------------

def _clean(stack: np.ndarray) -> np.ndarray:
    out = np.ascontiguousarray(stack, dtype=np.float32)
    # integer frames are finite: skip the check (a full pass over the frames)
    if np.asarray(stack).dtype.kind not in "biu" and not np.isfinite(out).all():
        out = out.copy()
        _fill_nonfinite(out)
    return out


def _clean_into(stack: np.ndarray, out: np.ndarray) -> None:
    """``_clean(stack)`` written into ``out`` (float32, the shape of ``stack``): no
    float32 copy of its own."""
    np.copyto(out, stack, casting="unsafe")
    if np.asarray(stack).dtype.kind not in "biu" and not np.isfinite(out).all():
        _fill_nonfinite(out)


def _fill_nonfinite(stack: np.ndarray) -> None:
    """In place: each frame's non-finite pixels take the median of its finite ones (0
    when it has none)."""
    for t in range(len(stack)):
        bad = ~np.isfinite(stack[t])
        if bad.any():
            good = stack[t][~bad]
            stack[t][bad] = np.median(good) if good.size else 0.0


def _robust_sigma(v: np.ndarray) -> float:
    if v.size == 0:
        return float(np.finfo(np.float32).tiny)
    return max(float(median_mad_sigma(v)[1]), float(np.finfo(np.float32).tiny))


def _sigma_map(r: np.ndarray, tile: int) -> np.ndarray:
    sig = median_mad_sigma(tile_samples(r, tile))[1]
    return tile_map(np.maximum(sig, np.finfo(np.float32).tiny), *r.shape)


def _tophat(frame: np.ndarray, size: int, guard: int) -> np.ndarray:
    se = cv2.getStructuringElement(cv2.MORPH_RECT, (size, size))
    return cv2.morphologyEx(frame, cv2.MORPH_TOPHAT, se, borderType=cv2.BORDER_REPLICATE)


#: unit steps (dx, dy) of the 4 line directions 0, 45, 90, 135 degrees, angles measured
#: in the (x, y) pixel frame (x = column, y = row, pointing down): atan2(dy, dx).
DIRECTIONS = ((1, 0), (1, 1), (0, 1), (-1, 1))


def _line_offsets(size: int, guard: int):
    r = size // 2
    return [k for k in range(-r, r + 1) if abs(k) > guard]


def _line_kernels(size: int, guard: int) -> list[np.ndarray]:
    r = size // 2
    ks = _line_offsets(size, guard)
    kernels = []
    for dx, dy in DIRECTIONS:
        k = np.zeros((size, size), np.float32)
        for s in ks:
            k[r + s * dy, r + s * dx] = 1.0 / len(ks)
        kernels.append(k)
    return kernels


def _maxmean(frame: np.ndarray, size: int, guard: int) -> np.ndarray:
    bg = None
    for k in _line_kernels(size, guard):
        m = cv2.filter2D(frame, cv2.CV_32F, k, borderType=cv2.BORDER_REFLECT)
        bg = m if bg is None else np.maximum(bg, m, out=bg)
    return frame - bg


def _maxmedian(frame: np.ndarray, size: int, guard: int) -> np.ndarray:
    r = size // 2
    h, w = frame.shape
    pad = cv2.copyMakeBorder(frame, r, r, r, r, cv2.BORDER_REFLECT)
    ks = _line_offsets(size, guard)
    bg = None
    for dx, dy in DIRECTIONS:
        samples = np.stack([pad[r + s * dy:r + s * dy + h, r + s * dx:r + s * dx + w]
                            for s in ks])
        m = np.median(samples, axis=0).astype(np.float32)
        bg = m if bg is None else np.maximum(bg, m, out=bg)
    return frame - bg


def _temporal(stack: np.ndarray, history: int, size: int, past: np.ndarray | None,
              future: np.ndarray | None = None, ahead: bool = False):
    n_past = 0 if past is None else len(past)
    n_all = n_past + len(stack) + (0 if future is None else len(future))

    def full(i):        # frame i of past + stack + future (no concatenated copy)
        if i < n_past:
            return past[i]
        if i < n_past + len(stack):
            return stack[i - n_past]
        return future[i - n_past - len(stack)]

    out = np.empty_like(stack)
    # running sum of the previous `history` frames: one add and one subtract per frame
    # (float32 is enough: the sum restarts from the frames themselves in every call)
    total = np.zeros(stack.shape[1:], np.float32)
    for i in range(max(0, n_past - history), n_past):
        _accumulate(past[i], total)
    for t in range(len(stack)):
        i = n_past + t
        count = i - max(0, i - history)
        if count == 0 and ahead and i + 1 < n_all:
            # the very first frame of a sequence has no past: the next frames stand in
            bg = np.mean([full(j) for j in range(i + 1, min(n_all, i + 1 + history))],
                         axis=0, dtype=np.float32)
            np.subtract(stack[t], bg, out=out[t])
        elif count == 0:        # no past, no future: a box mean stands in
            out[t] = stack[t] - cv2.blur(stack[t], (size, size), borderType=cv2.BORDER_REFLECT)
        else:
            cv2.scaleAdd(total, -1.0 / count, stack[t], dst=out[t])
        _accumulate(full(i), total)
        if i - history >= 0:
            total -= full(i - history)
    return out


#: long memory (``suppress(long_past=)``): a point's excess over the long-memory
#: background, in robust sigmas of that excess, that marks it
HOLD_K = 3.0
#: ... and the fewest long-memory frames it takes: the median of fewer is noisy, and its
#: dips, the same in every frame of a window, integrate like a still target
HOLD_MIN = 4
_HOLD_DILATE = np.ones((5, 5), np.uint8)


def _long_background(long_past, shape) -> np.ndarray:
    """The median over the long-memory frames (S, H, W) -> float32 (H, W)."""
    lp = np.asarray(long_past)
    if lp.ndim != 3 or lp.shape[1:] != tuple(shape):
        raise ValueError(f"long_past must have shape (S, {shape[0]}, {shape[1]}), "
                         f"got {lp.shape}")
    lp = _clean(lp)
    return lp[0].copy() if len(lp) == 1 else _median_axis0(lp)


def _keep_arrivals(residual: np.ndarray, stack: np.ndarray, long_bg: np.ndarray,
                   size: int) -> None:
    """In place, per frame: residual = max(residual, frame - long_bg) about small points
    that stand out against ``long_bg`` but were learnt by the short background (see
    ``suppress``, Notes: long memory)."""
    sigma = _robust_sigma((stack[0] - long_bg)[::2, ::2].ravel())
    excess = np.empty_like(long_bg)
    for frame, res in zip(stack, residual):   # a loop over the window's frames
        np.subtract(frame, long_bg, out=excess)
        cand = (excess > HOLD_K * sigma) & (res < 0.5 * excess)
        if not cand.any():
            continue
        n, lab, stats, _ = cv2.connectedComponentsWithStats(cand.view(np.uint8), connectivity=8)
        small = (stats[:, cv2.CC_STAT_WIDTH] <= size) & (stats[:, cv2.CC_STAT_HEIGHT] <= size)
        small[0] = False
        if not small.any():
            continue
        mask = cv2.dilate(small[lab].view(np.uint8), _HOLD_DILATE).view(bool)
        np.maximum(res, excess, out=res, where=mask)


def _accumulate(frame: np.ndarray, total: np.ndarray) -> None:
    """total += frame (float32 (H, W)); ``cv2.accumulate`` converts uint8 / uint16 /
    float32 frames on the fly, in one pass (numpy's mixed-type add buffers a cast)."""
    if frame.dtype in (np.uint8, np.uint16, np.float32):
        cv2.accumulate(frame, total)
    else:
        np.add(total, frame, out=total)


#: rows per band of ``_median_axis0`` (16 rows x 640 px x 31 frames: 1.3 MB)
MEDIAN_ROWS = 16


def registered_lags(i: int, *, history: int, gap: int, samples: int,
                    ahead: int = 0) -> list[int]:
    """Lags of the past frames in the background of frame ``i`` (frames 0..i-1 exist);
    with ``ahead`` > 0 and no such past, the negative lags -l of the frames i+l that
    exist (frames i+1..i+ahead): the same lags, mirrored."""
    span = np.unique(np.round(np.linspace(gap, gap + history - 1, samples)).astype(int))
    lags = [int(lag) for lag in span if lag <= i]
    if not lags and ahead:
        lags = [-int(lag) for lag in span if lag <= ahead]
    return lags


def _fixed_pattern(full: np.ndarray) -> np.ndarray:
    """Temporal median of the 3x3 high-pass: structure that stays put in the image.

    ``full`` (T, H, W) float32 -> (H, W). Made band by band of ``MEDIAN_ROWS`` rows, each
    band's median filter seeing one row of neighbours above and below (the same values as
    the whole frames' filter, whose border is replicated), so the high-pass is held for one
    band at a time rather than for the whole stack (31 frames of 640x512: 41 MB).
    """
    t, h, w = full.shape
    out = np.empty((h, w), np.float32)
    for a in range(0, h, MEDIAN_ROWS):      # a loop over bands of rows
        b = min(h, a + MEDIAN_ROWS)
        lo, hi = max(0, a - 1), min(h, b + 1)
        hp = np.empty((t, b - a, w), np.float32)
        for i in range(t):
            np.subtract(full[i, a:b], cv2.medianBlur(full[i, lo:hi], 3)[a - lo:b - lo],
                        out=hp[i])
        out[a:b] = _median_axis0(hp)
    return out


def _median_axis0(stack: np.ndarray) -> np.ndarray:
    """``np.median(stack, axis=0)`` (same values) of a stack (T, H, W) -> float32 (H, W).

    Band by band of ``MEDIAN_ROWS`` rows, each pixel's time series is made contiguous (one
    row per pixel) by ``cv2.transpose`` and sorted in place
    (``irdetect.robust.sorted_median``): numpy's sort of the strided transposed view
    copies it far more slowly, and a band holds a few MB where the whole stack's copies
    held 2 x T x H x W floats (measured: docs/results/throughput.md, "Footage").
    """
    t, h, w = stack.shape
    out = np.empty((h, w), np.float32)
    for a in range(0, h, MEDIAN_ROWS):      # a loop over bands of rows
        band = np.ascontiguousarray(stack[:, a:a + MEDIAN_ROWS].reshape(t, -1))
        out[a:a + MEDIAN_ROWS] = sorted_median(cv2.transpose(band),
                                               overwrite=True).reshape(-1, w)
    return out


def _registered(stack, past, camera, history, gap, tolerance, fixed_pattern, samples, size,
                future=None, ahead=False):
    # past: raw frames (any dtype), converted straight into the one float32 stack of
    # past, stack and future (no float32 copy of the past beside it)
    n_past = 0 if past is None else len(past)
    n_future = 0 if future is None else len(future)
    full = stack
    if n_past or n_future:
        full = np.empty((n_past + len(stack) + n_future, *stack.shape[1:]), np.float32)
        if n_past:
            _clean_into(past, full[:n_past])
        full[n_past:n_past + len(stack)] = stack
        if n_future:
            full[n_past + len(stack):] = future
    if fixed_pattern and len(full) >= 3:
        pattern = _fixed_pattern(full)
        if full is stack:
            full = full - pattern[None]
        else:                               # its own copy: no second stack
            full -= pattern[None]
    _, h, w = full.shape
    out = np.zeros_like(stack)
    kern = np.ones((2 * tolerance + 1, 2 * tolerance + 1), np.uint8) if tolerance else None
    for t in range(len(stack)):
        i = n_past + t
        lags = registered_lags(i, history=history, gap=gap, samples=samples,
                               ahead=len(full) - 1 - i if ahead else 0)
        if not lags:
            # the first `gap` frames of a sequence have no past that old and (lead_in
            # "tophat" or too short a sequence) no future: a spatial top-hat stands in
            out[t] = _tophat(full[i], size, 0)
            continue
        total = np.zeros((h, w), np.float32)
        count = np.zeros((h, w), np.float32)
        for lag in lags:      # a loop over a handful of past frames
            dx, dy = camera[i] - camera[i - lag]
            m = np.float32([[1, 0, dx], [0, 1, dy]])
            warped = cv2.warpAffine(full[i - lag], m, (w, h), flags=cv2.INTER_LINEAR,
                                    borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            # only pixels whose source lies wholly inside the shifted frame
            x0, x1 = max(0, int(np.ceil(dx))), max(0, int(np.floor(w - 1 + dx)) + 1)
            y0, y1 = max(0, int(np.ceil(dy))), max(0, int(np.floor(h - 1 + dy)) + 1)
            if x1 > x0 and y1 > y0:     # OpenCV adds in place on the views (faster)
                acc, seen = total[y0:y1, x0:x1], count[y0:y1, x0:x1]
                cv2.add(acc, warped[y0:y1, x0:x1], dst=acc)
                cv2.add(seen, 1.0, dst=seen)
        ok = count > 0
        bg = np.divide(total, count, out=full[i].copy(), where=ok)
        if kern is not None:
            bg = cv2.dilate(bg, kern, borderType=cv2.BORDER_REPLICATE)
        np.subtract(full[i], bg, out=out[t])
        out[t][~ok] = 0.0
    return out
