"""Bidirectional inter-frame correlation over 3 combined frames (Wan & Askar 2008, section 4).

A fused point of combined frame 1 starts a 3-point segment when a fused point of frame 2
lies within the motion bound l1 of it and a fused point of frame 3 lies within l2 of that
one (forward, eq. 5); the same search from frame 3 back to frame 1 is the backward
coefficient (eq. 6). Points on a segment are confirmed; the segment gives the velocity
v = s / t (eq. 8).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.spatial import cKDTree

from irdetect.robust import median_mad_sigma, tile_map, tile_samples
from irdetect.tables import SEGMENT, empty

RESOLVE = ("all", "unique", "cost")

#: score units worth the full ``max_deviation`` in the "cost" resolution: the cost of a
#: segment is deviation / max_deviation - mean score / SCORE_SCALE
SCORE_SCALE = 2.0


@dataclass(frozen=True)
class Correlation:
    """The 3-point segments found over combined frames (k, k+1, k+2).

    Attributes
    ----------
    segments : ndarray of dtype ``irdetect.tables.SEGMENT``
        One row per segment; ``segment_id`` and ``combined_frame`` are 0 (the pipeline
        numbers them), ``vx``, ``vy`` in px/frame, ``score`` the mean of the 3 points'
        scores (0 when the inputs carry none).
    index : ndarray of int64 of shape (n_segments, 3)
        Row of each segment's point in the 1st, 2nd and 3rd input.
    """

    segments: np.ndarray
    index: np.ndarray
    #: (n_segments, 3, 2) target position (x, y) of each segment at each input's
    #: ``Evidence.report`` time, from the verified straight track; NaN without evidence
    positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 2)))
    #: (n_segments,) the verification statistic (``track_significance``); NaN without evidence
    significance: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def confirmed(self, which: int, n: int) -> np.ndarray:
        """Bool mask over the ``n`` points of input ``which`` (0, 1, 2): on a segment."""
        out = np.zeros(n, dtype=bool)
        out[self.index[:, which]] = True
        return out


def motion_bound(step: int, max_speed: float, tolerance: float) -> float:
    """l1 = l2 = max_speed x step + tolerance (px, Chebyshev) between combined frames."""
    return max_speed * step + tolerance


@dataclass(frozen=True)
class Evidence:
    """The PSF-matched residual frames behind 3 combined frames (for ``verify``).

    Attributes
    ----------
    frames : ndarray of float32 of shape (F, H, W), or a sequence of (H, W) frames or of
        (F_j, H, W) blocks (F = sum F_j)
        Suppressed frames smoothed by the target's PSF (``matched_frame``): every frame
        of the 3 windows, each once. Blocks (the pipeline passes each window's frames)
        are sampled where they lie, without a stacked copy.
    index : ndarray of shape (F,)
        Frame index of each of ``frames``.
    times : tuple of 3 floats
        Frame index (fractional allowed) at which each input's fused points sit: the
        window's last frame for the ``dp`` projection, its middle for the others.
    report : tuple of 3 floats
        Frame index at which the verified positions of each input are reported (the
        window's middle).
    sigma : float
        Noise standard deviation of one matched frame (> 0).
    leads : tuple of floats
        Frames of motion by which the fused points may trail their targets; the search
        starts from each (``DP_LEADS`` for the ``dp`` projection, (0,) otherwise).
    shift : ndarray of shape (F, 2), optional
        Tracks in scene coordinates (beyond the paper): the camera's image offset (x, y)
        px of each frame (``irdetect.camera``), added to a track's position when its
        frame is sampled, so a track straight in the scene is followed through a
        panning or shaking camera; points, positions and velocities are then scene
        coordinates (image coordinates minus the offset). None: image coordinates.
    """

    frames: object
    index: np.ndarray
    times: tuple
    report: tuple
    sigma: float
    leads: tuple = (0.0,)
    shift: np.ndarray | None = None


def _frame_blocks(evidence: Evidence) -> tuple[list, np.ndarray, dict]:
    """The evidence frames as C-contiguous float32 blocks (F_j, H, W) (the pipeline's
    blocks in place where they are float32 already), each frame's time relative to the
    evidence's middle frame, float32 (F,), and the sampling's keywords for
    ``_sample_sum``: ``shift`` (F, 2) float32 or None and ``cap`` (``CLIP`` sigmas)."""
    frames = evidence.frames
    if isinstance(frames, np.ndarray):
        frames = [frames]
    elif len(frames) and np.ndim(frames[0]) == 2:
        frames = [np.stack(frames)]
    blocks = [np.ascontiguousarray(b, dtype=np.float32) for b in frames]
    t = np.asarray(evidence.index, np.float64)
    shift = None if evidence.shift is None else np.asarray(evidence.shift, np.float32)
    cap = np.float32(CLIP * evidence.sigma) if CLIP > 0 else None
    return blocks, (t - t.mean()).astype(np.float32), {"shift": shift, "cap": cap}


#: each frame's sample counts at most CLIP noise sigmas in a track sum (0 = no cap): a
#: straight track that crosses a bright target in one or two frames of 36 would otherwise
#: pass the verification (a target at per-frame SNR 30 gives z 16 to any track through
#: it), as would one bright clutter spot; a target of per-frame SNR up to CLIP keeps all
#: of its sum, a brighter one still sums CLIP sqrt(F) sigmas along its own track
CLIP = 8.0


#: the ``dp`` merit's fused point trails its target: the merit of the path's recent
#: pixels is almost as high as at its end, so the fused centroid of a target's blob sits
#: behind the target's position in the window's last frame, the more so the brighter the
#: target (measured on wan2008 at k 2.5: median 2.4 px at SNR 2, 4.2 at SNR 3, 5.7 at
#: SNR 4, 6.5 at SNR 6, targets at 1 px/frame); the first search stage starts from each
DP_LEADS = (1.0, 3.0, 5.0, 7.0)


def matched_frame(residual, smooth: float, out: np.ndarray | None = None) -> np.ndarray:
    """One suppressed frame smoothed by a Gaussian of ``smooth`` px (the PSF's matched
    filter), minus its median (on a 4-px grid).

    ``residual`` : ndarray (H, W); returns float32 (H, W), written into ``out`` (float32
    (H, W), may be ``residual`` itself) when given. ``smooth = 0``: no smoothing.
    """
    f = np.asarray(residual, dtype=np.float32)
    if smooth > 0:
        f = cv2.GaussianBlur(f, (0, 0), float(smooth), dst=out, borderType=cv2.BORDER_REFLECT)
    elif out is None:
        f = f.copy()
    elif out is not f:
        out[...] = f
        f = out
    # a suppressor may leave a non-zero level (the top-hat's residual is >= 0): summed
    # over many frames it would read as signal
    f -= np.float32(np.median(f[::4, ::4]))
    return f


def standardise(frames, tile: int = 32) -> list:
    """Divide a window's matched frames by their local robust noise scale (in place).

    ``frames``: sequence of (H, W) float32 matched frames of one window. The scale is
    1.4826 MAD per ``tile`` x ``tile`` block over every 3rd frame on a 2-px grid, bilinear
    between block centres, floored at a quarter of the median block's; a frame smaller
    than 2 tiles gets one scale. Structured clutter (cloud edges) then counts in units of
    its own residual level, as the CFAR of ``irdetect.detect`` does per combined frame.
    """
    frames = list(frames)
    if not frames:
        return frames
    h, w = frames[0].shape
    # every 3rd frame, every 2nd pixel of each tile: (ny, nx, samples)
    sub = tile_samples(np.stack([np.asarray(f) for f in frames[::3]]), tile, 2)
    sc = median_mad_sigma(np.moveaxis(sub, 0, -2).reshape(*sub.shape[1:3], -1))[1]
    sc = np.maximum(sc, max(0.25 * float(np.median(sc)), float(np.finfo(np.float32).tiny)))
    inv = tile_map(1.0 / sc, h, w)
    for f in frames:
        np.multiply(f, inv, out=f)
    return frames


def noise_level(frames) -> float:
    """Robust noise sd of matched frames: median over frames of 1.4826 MAD on a 4-px grid."""
    out = []
    for f in frames[::max(1, len(frames) // 6)]:
        out.append(float(median_mad_sigma(np.asarray(f)[::4, ::4].ravel())[1]))
    return float(max(np.median(out), np.finfo(np.float32).tiny)) if out else 1.0


#: the search of ``track_significance``: the coarse stage's 3 x 3 grid step (px, nearest
#: pixel, from each of ``Evidence.leads``), then the refinement's (position px,
#: velocity px/frame) 3 x 3 grid steps, each climbed for up to REFINE_ROUNDS rounds
_COARSE = 1.0
_REFINE = ((0.5, 0.05), (0.25, 0.025))
REFINE_ROUNDS = 3
_GRID = np.array(np.meshgrid((-1.0, 0.0, 1.0), (-1.0, 0.0, 1.0), indexing="ij")).reshape(2, -1).T


def track_significance(evidence: Evidence, points: np.ndarray, screen: float = -np.inf):
    """Velocity-matched filter along the straight track through 3-point segments.

    Parameters
    ----------
    evidence : Evidence
    points : ndarray of shape (n, 3, 2)
        (x, y) of each segment's 3 points, at ``evidence.times``.
    screen : float
        Segments whose statistic after the first (coarse) search stage is below
        ``screen`` are not refined further (their coarse values are returned).

    Returns
    -------
    z : ndarray of shape (n,)
        sum_t S_t(c + v (t - t_m)) / (sigma sqrt(F)) over the F evidence frames, maximised
        over c, v around the least-squares line through the points, started from each
        of ``evidence.leads``: the target's energy of all F frames integrated along its
        own path (about 9 for a wan2008 target at SNR 2, under 4 for chains of noise
        points).
    c : ndarray of shape (n, 2)
        Best position (x, y) at the middle frame t_m of the evidence.
    v : ndarray of shape (n, 2)
        Best velocity, px/frame.

    Notes
    -----
    The coarse stage takes the best of a 3 x 3 grid of ``_COARSE`` px around the line
    moved ahead by each lead, on the nearest pixel (a 1-px grid on PSF-smoothed
    frames). The refinement is a bilinear hill climb for each of the ``_REFINE`` steps
    (``_climb``): a round samples the 3 x 3 positions around c at velocity v and the
    3 x 3 velocities around v at position c, and moves both to their bests, until
    neither moves or ``REFINE_ROUNDS``. It reaches 3 steps away where one joint
    3 x 3 x 3 x 3 grid per step (the earlier search) reached one, with at most 108
    hypotheses per segment instead of 162. Sampling is by ``cv2.remap`` over all
    segments and hypotheses at once (``_sample_sum``), in chunks of segments
    (``_chunks``).
    """
    p = np.asarray(points, np.float64).reshape(-1, 3, 2)
    if len(p) == 0:
        return np.zeros(0), np.zeros((0, 2)), np.zeros((0, 2))
    frames, dts, kw = _frame_blocks(evidence)
    n_f = len(dts)
    tm = float(np.mean(evidence.index))
    times = np.asarray(evidence.times, np.float64)
    tt = times - times.mean()
    v = (tt[None, :, None] * (p - p.mean(1, keepdims=True))).sum(1) / (tt ** 2).sum()
    c = p.mean(1) + v * (tm - times.mean())
    norm = evidence.sigma * np.sqrt(n_f)
    z = np.zeros(len(p))
    # coarse: from each lead, the line moved ahead by lead frames of its own motion
    lead = np.repeat(np.asarray(evidence.leads, np.float64), len(_GRID))
    grid = np.tile(_COARSE * _GRID, (len(evidence.leads), 1))
    for r in _chunks(np.arange(len(p)), frames, len(grid) * n_f):
        cc = c[r, None, :] + v[r, None, :] * lead[None, :, None] + grid[None]
        total = _sample_sum(frames, dts, cc, v[r, None, :], bilinear=False, **kw)
        best = total.argmax(1)
        k = np.arange(len(r))
        c[r], z[r] = cc[k, best], total[k, best] / norm
    live = np.flatnonzero(z >= screen)
    for dc, dv in _REFINE:
        rows = live
        for _ in range(REFINE_ROUNDS):
            if len(rows) == 0:
                break
            rows = np.concatenate([_climb(frames, dts, r, c, v, z, norm, dc * _GRID,
                                          dv * _GRID, kw)
                                   for r in _chunks(rows, frames, 2 * len(_GRID) * n_f)])
        if len(rows):
            # still moving after the last round: the statistic where c, v are now
            z[rows] = _sample_sum(frames, dts, c[rows, None], v[rows, None], True,
                                  **kw)[:, 0] / norm
    return z, c, v


def _chunks(rows, frames, samples_per_row):
    """``rows`` in chunks of at most ``_budget(frames)`` samples (at least one row each):
    the temporaries of a search stay bounded whatever the number of segments."""
    step = max(1, _budget(frames) // samples_per_row)
    return [rows[a:a + step] for a in range(0, len(rows), step)]


def _climb(frames, dts, rows, c, v, z, norm, dcs, dvs, kw=None) -> np.ndarray:
    """One round of the hill climb of ``track_significance`` for ``rows``.

    Samples the positions c + dcs at velocity v and the velocities v + dvs at position
    c (``dcs``, ``dvs`` (9, 2), each with a zero row) in one call, and moves c and v of
    each row to their bests in place; z gets the larger of the two best statistics (the
    statistic at the new c, v unless both moved). Returns the rows that moved.
    """
    r, nc, nv = rows, len(dcs), len(dvs)
    cc = np.concatenate([c[r, None] + dcs, np.repeat(c[r, None], nv, 1)], 1)
    vv = np.concatenate([np.repeat(v[r, None], nc, 1), v[r, None] + dvs], 1)
    total = _sample_sum(frames, dts, cc, vv, bilinear=True, **(kw or {}))
    bc, bv = total[:, :nc].argmax(1), nc + total[:, nc:].argmax(1)
    k = np.arange(len(r))
    z[r] = np.maximum(total[k, bc], total[k, bv]) / norm
    c[r], v[r] = cc[k, bc], vv[k, bv]
    return r[(dcs[bc] != 0).any(1) | (dvs[bv - nc] != 0).any(1)]


#: a verified track must be a point: its statistic at RING_PX px to either side, in 8
#: directions, stays under RING_RATIO of its own (an edge or a blob of clutter residual
#: that moves coherently scores about as high beside the track as on it)
RING_PX = 3.0
RING_RATIO = 0.5
RING_MAX = 8.0


def ring_significance(evidence: Evidence, c: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Largest matched-filter statistic of the tracks beside each track, velocity v,
    over the track's own: (n,).

    The tracks beside are 8 directions at RING_PX px, or 2.5 times the target's own
    width where it is wider (measured from the mean of the sums 1.5 px out in 8
    directions: a Gaussian of sigma s keeps exp(-1.125 / s^2) of its sum there), up to
    RING_MAX px: a broad target (PSF sigma 2 px keeps 40 % of its peak 3 px out) is not
    an edge. The trade-off against RING_MAX = RING_PX on real data is section 4 of
    docs/results/real.md (``scripts/bench_real.py``). Sums without ``CLIP``: the cap would
    make a bright target as strong beside its track as on it.
    """
    if len(c) == 0:
        return np.zeros(0)
    a = np.deg2rad(np.arange(0, 360, 45))
    unit = np.column_stack([np.cos(a), np.sin(a)])
    near, _ = _parallel_sums(evidence, c, v, np.vstack([[0.0, 0.0], 1.5 * unit]), cap=False)
    own = np.maximum(near[:, 0], np.float32(1e-30))
    keep = np.clip(near[:, 1:].mean(axis=1) / own, 1e-6, 1 - 1e-6)
    width = np.sqrt(1.125 / -np.log(keep))                          # px, per track
    radius = np.clip(2.5 * width, RING_PX, RING_MAX)
    total, _ = _parallel_sums(evidence, c, v, radius[:, None, None] * unit[None], cap=False)
    return total.max(axis=1) / own


def _parallel_sums(evidence: Evidence, c, v, offsets, cap: bool = True):
    """Track sums (n, R) float32 of the tracks c + offsets[r], velocity v (offsets (R, 2)
    px, or (n, R, 2) per track), bilinear (each sample capped at ``CLIP`` sigmas unless
    ``cap`` is False), and the number of frames F they sum over."""
    frames, dts, kw = _frame_blocks(evidence)
    if not cap:
        kw = {**kw, "cap": None}
    offsets = np.asarray(offsets, np.float64)
    cc = c[:, None, :] + (offsets if offsets.ndim == 3 else offsets[None])
    return _sample_sum(frames, dts, cc, v[:, None, :], bilinear=True, **kw), len(dts)


#: the local test of a verified track (``local_significance``): parallel tracks at these
#: distances in px, LOCAL_ANGLES directions each (staggered by half a step per radius).
#: Clear of a target's own wings: with (4, 7) the broader target of the easy1 recording
#: raised its own ring (local z 3.5) and was lost
LOCAL_RADII = (5.0, 8.0)
LOCAL_ANGLES = 16


def local_significance(evidence: Evidence, c: np.ndarray, v: np.ndarray,
                       z: np.ndarray) -> np.ndarray:
    """How far a verified track stands out of the clutter it runs through.

    Parameters
    ----------
    evidence : Evidence
    c, v : ndarray of shape (n, 2)
        Verified tracks (``track_significance``): position (x, y) at the evidence's
        middle frame, velocity in px/frame.
    z : ndarray of shape (n,)
        Their statistics (``track_significance`` units).

    Returns
    -------
    ndarray of shape (n,)
        (z - m) / max(1, s): m the median and s 1.4826 x the MAD of the statistics of
        the parallel tracks c + (r cos a, r sin a), velocity v, for r in ``LOCAL_RADII``
        and ``LOCAL_ANGLES`` angles a: the track's significance against the local
        null distribution of track sums instead of against independent noise.

    Notes
    -----
    Beyond the paper. ``track_significance`` divides by sigma sqrt(F), the spread of a
    track sum over F independent frames. On real backgrounds the registered residual
    is correlated in time (clutter residue stays at its scene point for many frames):
    on the DAUB sequences the spread of track sums at random places is 2.4-6 times
    sigma sqrt(F) (simulator: 0.8-1.0), so textured ground passes ``verify`` while a
    target in a quiet patch would pass anyway. The floor 1 keeps the test no stricter
    than ``verify`` where the clutter is white noise.
    """
    if len(c) == 0:
        return np.zeros(0)
    a = np.arange(LOCAL_ANGLES) * (2 * np.pi / LOCAL_ANGLES)
    ring = np.concatenate([r * np.column_stack([np.cos(a + i * np.pi / LOCAL_ANGLES),
                                                np.sin(a + i * np.pi / LOCAL_ANGLES)])
                           for i, r in enumerate(LOCAL_RADII)])          # (R x A, 2)
    s, n_f = _parallel_sums(evidence, c, v, ring)
    s = s.astype(np.float64) / (evidence.sigma * np.sqrt(n_f))
    med, spread = median_mad_sigma(s)
    return (np.asarray(z, np.float64) - med) / np.maximum(spread, 1.0)


#: samples (segments x hypotheses x frames) per chunk of ``_sample_sum``'s maps: an 8th
#: of the evidence's size (temporaries bounded by the evidence the pipeline holds
#: anyway), within these limits
CHUNK = 1 << 13
CHUNK_MAX = 1 << 18
#: rows of the tall image of one ``cv2.remap`` call at most (frames of more rows: one
#: each); cv2.remap itself takes images and maps of fewer than SHRT_MAX rows
TALL_ROWS = 8192
_SHRT_MAX = 32767


def _budget(blocks) -> int:
    return max(CHUNK, min(CHUNK_MAX, sum(b.size for b in blocks) // 8))


def _sample_sum(blocks, dts, cc, vv, bilinear, shift=None, cap=None):
    """Track sums: sum_f S_f(c + v dts[f] + shift[f]) over the evidence frames, per
    hypothesis.

    Parameters
    ----------
    blocks : list of float32 ndarray (F_j, H, W)
        The evidence frames S_f in blocks (F = sum F_j), C-contiguous.
    dts : ndarray of shape (F,)
        Each frame's time relative to the evidence's middle frame.
    cc : ndarray of shape (n, hyp, 2)
        Track positions (x, y) at the middle frame.
    vv : ndarray of shape (n, hyp, 2) or (n, 1, 2)
        Velocities (x, y) in px/frame.
    bilinear : bool
        Bilinear interpolation, else the nearest pixel.
    shift : ndarray of shape (F, 2), optional
        Each frame's offset (x, y) added to the track's position (``Evidence.shift``).
    cap : float, optional
        Each frame's sample counts at most ``cap`` (``CLIP`` x the evidence's sigma).

    Returns
    -------
    ndarray of float32, shape (n, hyp)

    Notes
    -----
    A block of frames is one tall (F_j H, W) image, so one ``cv2.remap`` samples every
    hypothesis in all of its frames: positions are clamped to the frame (the border
    pixels' values outside it) and frame f's rows are offset by f H. The maps of all F
    frames are computed at once, (F, segments x hyp), one row per frame.
    """
    f32 = np.float32
    n, hyp = cc.shape[:2]
    h = blocks[0].shape[1]
    inter = cv2.INTER_LINEAR if bilinear else cv2.INTER_NEAREST
    # the tall images: cv2.remap takes fewer than SHRT_MAX rows, and float32 row
    # coordinates under TALL_ROWS keep 1/1000 px; frames of more rows: one each
    tall, rows = [], []
    for block in blocks:
        per = max(1, min(len(block), TALL_ROWS // h))
        for lo in range(0, len(block), per):
            sub = block[lo:lo + per]
            tall.append(sub.reshape(-1, sub.shape[2]))
            rows.append(h * np.arange(len(sub), dtype=f32))
    rows = np.concatenate(rows)[:, None, None]                          # (F, 1, 1)
    dt = np.asarray(dts, f32)[:, None, None]
    n_f = len(dt)
    total = np.zeros((n, hyp), f32)
    x0, y0 = cc[..., 0].astype(f32), cc[..., 1].astype(f32)           # (n, hyp)
    vx, vy = vv[..., 0].astype(f32), vv[..., 1].astype(f32)           # (n, hyp or 1)
    chunk = max(1, min(n, _budget(blocks) // (hyp * n_f), (_SHRT_MAX - 1) // hyp))
    for a in range(0, n, chunk):             # one round unless n x hyp x F is large
        sl = slice(a, a + chunk)
        k = len(total[sl])
        mx = np.empty((n_f, k, hyp), f32)
        my = np.empty((n_f, k, hyp), f32)
        np.multiply(vx[sl], dt, out=mx)
        mx += x0[sl]
        np.multiply(vy[sl], dt, out=my)
        my += y0[sl]
        if shift is not None:
            mx += shift[:, 0, None, None]
            my += shift[:, 1, None, None]
        np.clip(my, 0, h - 1, out=my)
        my += rows
        first = 0
        for img in tall:
            m = len(img) // h
            s = cv2.remap(img, mx[first:first + m].reshape(m, k * hyp),
                          my[first:first + m].reshape(m, k * hyp), inter,
                          borderMode=cv2.BORDER_REPLICATE)
            if cap is not None:
                np.minimum(s, cap, out=s)
            total[sl] += s.reshape(m, k, hyp).sum(axis=0)
            first += m
    return total


def correlate(points1, points2, points3, step: int, evidence: Evidence | None = None, *,
              max_speed: float = 2.0, tolerance: float = 5.0,
              constant_velocity: bool = True, max_deviation: float = 20.0,
              resolve: str = "cost", min_score: float = 3.5,
              verify: float = 6.5, verify_local: float = 3.5,
              screen: float = 0.4) -> Correlation:
    """Find 3-point segments through the fused points of 3 consecutive combined frames.

    Parameters
    ----------
    points1, points2, points3 : structured ndarray with fields ``x``, ``y`` (and
        optionally ``score``), or ndarray of shape (N, 2) of (x, y)
        Fused points (x = column, y = row, px) of combined frames k, k+1, k+2.
    step : int
        Frames between the starts of consecutive combined frames (the time t between
        them), ``CombineConfig.step``.
    evidence : Evidence, optional
        The matched residual frames behind the 3 combined frames (the pipeline passes
        them). With it and ``verify`` > 0, every chain is verified by a velocity-matched
        filter over all the frames of the 3 windows (``track_significance``).
    max_speed : float
        Largest target speed in px/frame (>= 0); with ``tolerance`` it gives the
        paper's motion bounds l1 = l2 = max_speed x step + tolerance.
    tolerance : float
        Position uncertainty of a fused point in px (>= 0), added to the motion bound.
    constant_velocity : bool
        Beyond the paper: also require |p1 - 2 p2 + p3| <= ``max_deviation`` (the middle
        point within reach of the midpoint of the outer two: straight, uniform motion).
    max_deviation : float
        Largest deviation from constant velocity in px (> 0), Euclidean.
    min_score : float
        Beyond the paper (0 = off): the mean score (CFAR z) of the 3 points must reach
        it. With the verification, a cheap pre-screen (3.5); without it, the earlier
        default's test (5, with ``k`` 3.5 in ``irdetect.detect``).
    verify : float
        Beyond the paper (0 = off): with ``evidence``, keep a chain only when the
        velocity-matched filter along its straight track reaches ``verify`` noise sigmas
        (a track-before-detect test over every frame of the 3 windows) and the track is
        a point (``ring_significance`` under ``RING_RATIO`` of it); "cost" then
        takes chains by decreasing significance and also drops a chain whose verified
        track runs within ``tolerance`` px of an accepted one in all 3 windows (one
        target, two chains). Segments then carry the verified velocity, and
        ``Correlation.positions`` the verified positions.
    verify_local : float
        Beyond the paper (0 = off, the earlier behaviour): with the verification, a
        verified track must also stand ``verify_local`` robust sigmas above the
        parallel tracks around it (``local_significance``): a local CFAR test of the
        track sum, for clutter whose residue is correlated in time.
    screen : float
        Beyond the paper, a speed/recall trade-off of the verification (0 <= screen
        <= 1): chains whose coarse statistic (the first, nearest-pixel search stage of
        ``track_significance``) is under ``screen`` x ``verify`` are not refined and
        fail. 0.4 (0.5 before: it lost daub-data14's first window, whose target's
        coarse value lies between 0.4 and 0.5 ``verify``, its refined one at 24.8). The
        share of chains refined, and the time, grow fast below it
        (docs/results/verification.md, ``scripts/bench_verification.py``).
    resolve : {"cost", "unique", "all"}
        What to do when a point lies on several segments. ``all``: keep every segment
        (the literal set-valued eqs. 5-7). ``unique``: the paper's reading that
        correspondence is unique both ways: keep a segment only when its first point
        starts exactly one forward segment and its last point exactly one backward
        segment. ``cost`` (beyond the paper): one-to-one, taking segments greedily by
        increasing cost |p1 - 2 p2 + p3| / max_deviation - (mean point score) / 2, so
        no point serves twice in one role and a strong straight segment wins over a
        weak noise point that happens to lie a little straighter.

    Returns
    -------
    Correlation
        Segments and the row indices of their points.

    Notes
    -----
    Eq. 5: R123(x, y) = g[f(x,y,1) sum_{p1,q1 in [-l1,l1]} sum_{p2,q2 in [-l2,l2]}
    f(x+p1, y+q1, 2) f(x+p1+p2, y+q1+q2, 3)], g(v) = [v > 0] (eq. 7; the print's
    y+q2 in the second factor is a typo for y+q1). Eq. 6 is the same from frame 3.
    We evaluate both on the fused points with KD-trees in the Chebyshev metric (all
    pairs within l1, then all pairs within l2 of the middle points, joined), not on
    binary images with 4 nested sums: the chains found are exactly those with
    R123 = 1 at their first point and R321 = 1 at their last. Velocity (eq. 8):
    v = (p3 - p1) / (2 step) px/frame. The paper's l1, l2 are not given; we derive them
    from a maximum speed.

    Examples
    --------
    >>> import numpy as np
    >>> c = correlate(np.array([[10., 10.]]), np.array([[22., 10.]]),
    ...               np.array([[34., 11.]]), step=12, min_score=0)
    >>> len(c.segments), float(c.segments["vx"][0])
    (1, 1.0)

    With ``evidence`` the first detection can run at a low threshold: chains of noise
    points are many, but their matched-filter significance stays under about 4 while a
    target's is about 9 at SNR 2 (wan2008).
    """
    pts = [_as_points(p, f"points{i + 1}") for i, p in enumerate((points1, points2, points3))]
    if int(step) != step or step < 1:
        raise ValueError(f"step must be an integer >= 1, got {step!r}")
    if not np.isfinite(max_speed) or max_speed < 0:
        raise ValueError(f"max_speed must be a number >= 0, got {max_speed!r}")
    if not np.isfinite(tolerance) or tolerance < 0:
        raise ValueError(f"tolerance must be a number >= 0, got {tolerance!r}")
    if not np.isfinite(max_deviation) or max_deviation <= 0:
        raise ValueError(f"max_deviation must be a positive number, got {max_deviation!r}")
    if not np.isfinite(min_score):
        raise ValueError(f"min_score must be a finite number, got {min_score!r}")
    if resolve not in RESOLVE:
        raise ValueError(f"resolve must be one of {RESOLVE}, got {resolve!r}")
    if not np.isfinite(verify) or verify < 0:
        raise ValueError(f"verify must be a number >= 0, got {verify!r}")
    if not np.isfinite(verify_local) or verify_local < 0:
        raise ValueError(f"verify_local must be a number >= 0, got {verify_local!r}")
    if not np.isfinite(screen) or not 0 <= screen <= 1:
        raise ValueError(f"screen must be a number in [0, 1], got {screen!r}")
    if evidence is not None and not isinstance(evidence, Evidence):
        raise ValueError(f"evidence must be an Evidence, got {type(evidence).__name__}")
    scores = [_scores(p) for p in (points1, points2, points3)]
    bound = motion_bound(int(step), float(max_speed), float(tolerance))
    index = _chains(pts, bound)
    p1, p2, p3 = (pts[i][index[:, i]] for i in range(3))
    deviation = np.hypot(*(p1 - 2 * p2 + p3).T) if len(index) else np.zeros(0)
    if constant_velocity:
        keep = deviation <= max_deviation
        index, deviation = index[keep], deviation[keep]
    if min_score > 0 and len(index):
        mean_score = sum(scores[i][index[:, i]] for i in range(3)) / 3.0
        keep = mean_score >= min_score
        index, deviation = index[keep], deviation[keep]
    if evidence is not None and verify > 0:
        return _verified(pts, scores, index, int(step), evidence, float(verify), resolve,
                         float(tolerance), float(verify_local), float(screen))
    if resolve == "unique":
        index, deviation = _unique(index, deviation)
    elif resolve == "cost":
        mean_score = sum(scores[i][index[:, i]] for i in range(3)) / 3.0 if len(index) else deviation
        index, deviation = _greedy(index, deviation / max_deviation - mean_score / SCORE_SCALE)
    return Correlation(segments=_segments(pts, scores, index, int(step)), index=index,
                       positions=np.full((len(index), 3, 2), np.nan),
                       significance=np.full(len(index), np.nan))


def _verified(pts, scores, index, step, evidence, verify, resolve, tolerance,
              verify_local, screen) -> Correlation:
    points = (np.stack([pts[i][index[:, i]] for i in range(3)], axis=1) if len(index)
              else np.zeros((0, 3, 2)))
    z, c, v = track_significance(evidence, points, screen=screen * verify)
    keep = z >= verify
    index, z, c, v = index[keep], z[keep], c[keep], v[keep]
    if len(z) and RING_RATIO > 0:
        keep = ring_significance(evidence, c, v) <= RING_RATIO
        index, z, c, v = index[keep], z[keep], c[keep], v[keep]
    if len(z) and verify_local > 0:
        keep = local_significance(evidence, c, v, z) >= verify_local
        index, z, c, v = index[keep], z[keep], c[keep], v[keep]
    tm = float(np.mean(evidence.index))
    report = np.asarray(evidence.report, np.float64) - tm
    positions = c[:, None, :] + v[:, None, :] * report[None, :, None]      # (n, 3, 2)
    if resolve == "cost":
        sel = _greedy_tracks(index, -z, positions, tolerance)
    elif resolve == "unique":
        sel = _unique_rows(index)
    else:
        sel = np.arange(len(index))
    index, z, positions, v = index[sel], z[sel], positions[sel], v[sel]
    segments = _segments(pts, scores, index, step)
    segments["vx"], segments["vy"] = v[:, 0], v[:, 1]
    return Correlation(segments=segments, index=index, positions=positions, significance=z)


def _unique_rows(index) -> np.ndarray:
    if len(index) == 0:
        return np.zeros(0, np.int64)
    fwd = np.bincount(index[:, 0])[index[:, 0]]
    bwd = np.bincount(index[:, 2])[index[:, 2]]
    return np.flatnonzero((fwd == 1) & (bwd == 1))


def _greedy_tracks(index, cost, positions, tolerance) -> np.ndarray:
    """Rows taken greedily by increasing cost: one-to-one in points, and no two tracks
    within ``tolerance`` px of each other in all 3 windows (a loop over the chains that
    passed verification: a handful per frame)."""
    used = [set(), set(), set()]
    keep: list[int] = []
    for s in np.argsort(cost, kind="stable"):
        i1, i2, i3 = index[s]
        if i1 in used[0] or i2 in used[1] or i3 in used[2]:
            continue
        if keep and (np.hypot(*(positions[keep] - positions[s]).transpose(2, 0, 1))
                     <= tolerance).all(axis=1).any():
            continue
        used[0].add(i1), used[1].add(i2), used[2].add(i3)
        keep.append(s)
    return np.sort(np.array(keep, dtype=np.int64))


def _as_points(p, name) -> np.ndarray:
    a = np.asarray(p)
    if a.dtype.names is not None:
        if "x" not in a.dtype.names or "y" not in a.dtype.names:
            raise ValueError(f"{name} must have fields x and y, got {a.dtype.names}")
        out = np.column_stack([a["x"], a["y"]]).astype(np.float64)
    else:
        if a.size == 0:
            return np.zeros((0, 2))
        if a.ndim != 2 or a.shape[1] != 2:
            raise ValueError(f"{name} must have shape (N, 2), got {a.shape}")
        out = a.astype(np.float64)
    if not np.isfinite(out).all():
        raise ValueError(f"{name} must be finite")
    return out.reshape(-1, 2)


def _scores(p) -> np.ndarray:
    a = np.asarray(p)
    if a.dtype.names is not None and "score" in a.dtype.names:
        return a["score"].astype(np.float64)
    return np.zeros(len(a))


def _pairs(a: np.ndarray, b: np.ndarray, bound: float) -> np.ndarray:
    if len(a) == 0 or len(b) == 0:
        return np.zeros((0, 2), np.int64)
    m = cKDTree(a).sparse_distance_matrix(cKDTree(b), bound, p=np.inf, output_type="ndarray")
    return np.column_stack([m["i"], m["j"]]).astype(np.int64)


def _chains(pts, bound) -> np.ndarray:
    """All (i1, i2, i3) with |p2 - p1|_inf <= bound and |p3 - p2|_inf <= bound."""
    a = _pairs(pts[0], pts[1], bound)      # forward: frame 1 -> frame 2
    b = _pairs(pts[1], pts[2], bound)      # frame 2 -> frame 3
    if len(a) == 0 or len(b) == 0:
        return np.zeros((0, 3), np.int64)
    b = b[np.argsort(b[:, 0], kind="stable")]
    lo = np.searchsorted(b[:, 0], a[:, 1], side="left")
    hi = np.searchsorted(b[:, 0], a[:, 1], side="right")
    n = hi - lo
    rep = np.repeat(np.arange(len(a)), n)
    offs = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    j = lo[rep] + offs
    return np.column_stack([a[rep, 0], a[rep, 1], b[j, 1]]).astype(np.int64)


def _unique(index, deviation):
    if len(index) == 0:
        return index, deviation
    fwd = np.bincount(index[:, 0])[index[:, 0]]   # segments starting at this frame-1 point
    bwd = np.bincount(index[:, 2])[index[:, 2]]   # segments ending at this frame-3 point
    keep = (fwd == 1) & (bwd == 1)
    return index[keep], deviation[keep]


def _greedy(index, deviation):
    if len(index) <= 1:
        return index, deviation
    order = np.argsort(deviation, kind="stable")
    used = [set(), set(), set()]
    keep = []
    for s in order:          # a loop over candidate segments (a handful per frame)
        i1, i2, i3 = index[s]
        if i1 in used[0] or i2 in used[1] or i3 in used[2]:
            continue
        used[0].add(i1), used[1].add(i2), used[2].add(i3)
        keep.append(s)
    keep = np.sort(np.array(keep, dtype=np.int64))
    return index[keep], deviation[keep]


def _segments(pts, scores, index, step) -> np.ndarray:
    if len(index) == 0:
        return empty(SEGMENT)
    out = np.zeros(len(index), dtype=SEGMENT)
    for i, (xf, yf) in enumerate((("x1", "y1"), ("x2", "y2"), ("x3", "y3"))):
        out[xf] = pts[i][index[:, i], 0]
        out[yf] = pts[i][index[:, i], 1]
    out["vx"] = (out["x3"] - out["x1"]) / (2 * step)
    out["vy"] = (out["y3"] - out["y1"]) / (2 * step)
    out["score"] = sum(scores[i][index[:, i]] for i in range(3)) / 3.0
    return out
