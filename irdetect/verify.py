"""Verification of chains by a velocity-matched filter (beyond the paper).

irdetect's own stage between the paper's bidirectional correlation (``irdetect.correlate``)
and track initiation: a chain of 3 fused points is kept only when the suppressed frames of
all 3 windows, smoothed by the PSF (``matched_frame``, ``standardise``), sum to a
significant value along its straight track (``track_significance``, a track-before-detect
test over every frame), the track is a point (``ring_significance``) and it stands out of
the clutter beside it (``local_significance``). ``verify_tracks`` runs the three tests.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from irdetect.kernels.sampling import climb, patch_sums, row_order, track_sums
from irdetect.robust import (median, median_mad_sigma, tile_map, tile_samples,
                              upper_sigma)


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


def _frame_blocks(evidence: Evidence) -> tuple[tuple, np.ndarray, dict]:
    """The evidence as the kernels take it: its frames as 3 C-contiguous float32 blocks
    (F_j, H, W) (``_three``; the pipeline's blocks in place where they are float32
    already), each frame's time relative to the evidence's middle frame, float32 (F,),
    and the sampling's keywords: ``shift`` (F, 2) float32 (zeros for a still camera) and
    ``cap`` (``CLIP`` sigmas, float32; inf for no cap)."""
    frames = evidence.frames
    if isinstance(frames, np.ndarray):
        frames = [frames]
    elif len(frames) and np.ndim(frames[0]) == 2:
        frames = [np.stack(frames)]
    t = np.asarray(evidence.index, np.float64)
    dts, shift, cap = _kernel_args(t - t.mean(), evidence.shift,
                                   CLIP * evidence.sigma if CLIP > 0 else None)
    return _three(frames), dts, {"shift": shift, "cap": cap}


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
    f -= np.float32(median(f[::4, ::4]))
    return f


def quantisation_floor(frame, smooth: float) -> float:
    """The noise scale of a matched residual that its frames' quantisation alone gives.

    Frames of whole grey levels hold each value to within half a grey level: a uniform
    error of standard deviation 1 / sqrt(12) grey levels per pixel, which the matched
    filter (a Gaussian of ``smooth`` px) scales by its kernel's L2 norm (about
    1 / (2 sqrt(pi) ``smooth``)). A residual whose measured scale falls below this holds
    no information at that level: a lossy video codec copies the blocks of a still scene
    from frame to frame bit for bit, and an 8-bit recording of a quiet scene repeats its
    grey levels, so that 1.4826 MAD of a tile is 0.

    Parameters
    ----------
    frame : ndarray of shape (H, W)
        One frame as read: integer frames, and float frames whose values are all whole
        (a MATLAB ``double`` of an 8-bit video), are quantised to whole grey levels.
    smooth : float
        Sigma (px) of the matched filter's Gaussian; 0: none.

    Returns
    -------
    float
        The floor in grey levels: 0.289 x the kernel's L2 norm for whole grey levels
        (0.143 at ``smooth`` 0.6, 0.081 at 1), 0 for float frames of other values (their
        quantisation is not known).
    """
    f = np.asarray(frame)
    if not np.issubdtype(f.dtype, np.integer):
        values = f[np.isfinite(f)]
        if not values.size or not np.array_equal(values, np.round(values)):
            return 0.0
    if smooth <= 0:
        return float(np.sqrt(1 / 12))
    # the 1-D kernel of matched_frame's GaussianBlur (its size for float images); the 2-D
    # kernel is its outer product, whose L2 norm is the sum of its squares
    k = cv2.getGaussianKernel(int(round(8 * smooth + 1)) | 1, float(smooth), cv2.CV_64F)
    return float(np.sqrt(1 / 12) * np.sum(k ** 2))


def standardise(frames, tile: int = 32, floor: float = 0.0) -> list:
    """Divide a window's matched frames by their local robust noise scale (in place).

    ``frames``: sequence of (H, W) float32 matched frames of one window. The scale is
    1.4826 MAD per ``tile`` x ``tile`` block over every 3rd frame on a 2-px grid, bilinear
    between block centres, floored at a quarter of the median block's and at ``floor``
    (grey levels: ``quantisation_floor`` of frames of whole grey levels); a frame smaller
    than 2 tiles gets one scale. Structured clutter (cloud edges) then counts in units of
    its own residual level, as the CFAR of ``irdetect.detect`` does per combined frame.
    Without ``floor``, an H.264 video's still scene (blocks copied bit for bit: MAD 0 in
    most tiles) gave local SNRs of 1e3-1e6.
    """
    frames = list(frames)
    if not frames:
        return frames
    h, w = frames[0].shape
    # every 3rd frame, every 2nd pixel of each tile: (ny, nx, samples)
    sub = tile_samples(np.stack([np.asarray(f) for f in frames[::3]]), tile, 2)
    sc = median_mad_sigma(np.moveaxis(sub, 0, -2).reshape(*sub.shape[1:3], -1))[1]
    sc = np.maximum(sc, max(0.25 * float(np.median(sc)), float(floor),
                            float(np.finfo(np.float32).tiny)))
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


#: the search of ``track_significance``: the coarse stage's 3 x 3 grid of 1 px (the
#: nearest pixel, from each of ``Evidence.leads``), then the refinement's (position px,
#: velocity px/frame) 3 x 3 grid steps, each climbed for up to REFINE_ROUNDS rounds
_REFINE = ((0.5, 0.05), (0.25, 0.025))
REFINE_ROUNDS = 3
_GRID = np.ascontiguousarray(
    np.array(np.meshgrid((-1.0, 0.0, 1.0), (-1.0, 0.0, 1.0), indexing="ij")).reshape(2, -1).T)


def track_significance(evidence: Evidence, points: np.ndarray, screen: float = -np.inf):
    """Velocity-matched filter along the straight track through 3-point segments.

    Parameters
    ----------
    evidence : Evidence
    points : ndarray of shape (n, 3, 2)
        (x, y) of each segment's 3 points, at ``evidence.times``.
    screen : float
        Segments whose statistic after the first (coarse) search stage, or after a
        refinement step, is below ``screen`` are not refined further (their values
        there are returned).

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
    The coarse stage takes the best of a 3 x 3 grid of 1 px around the line
    moved ahead by each lead, on the nearest pixel (a 1-px grid on PSF-smoothed
    frames). The refinement is a bilinear hill climb for each of the ``_REFINE`` steps
    (``_refine``): a round samples the 3 x 3 positions around c at velocity v and the
    3 x 3 velocities around v at position c, and moves both to their bests, until
    neither moves or ``REFINE_ROUNDS``. It reaches 3 steps away where one joint
    3 x 3 x 3 x 3 grid per step (the earlier search) reached one, with at most 108
    hypotheses per segment instead of 162. Both stages are compiled kernels
    (``irdetect.kernels.sampling``: ``patch_sums``, ``climb``).
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
    grid = np.tile(_GRID, (len(evidence.leads), 1))
    cc = c[:, None, :] + v[:, None, :] * lead[None, :, None] + grid[None]
    total = _grid_sums(frames, dts, c, v, evidence.leads, **kw)
    best = total.argmax(1)
    k = np.arange(len(p))
    c, z[:] = cc[k, best], total[k, best] / norm
    _refine(frames, dts, c, v, z, np.flatnonzero(z >= screen), norm, screen, kw)
    return z, c, v


def _refine(frames, dts, c, v, z, rows, norm, screen, kw) -> None:
    """The hill climb of ``track_significance`` for ``rows`` (those past the coarse
    screen), c, v and z in place (the compiled ``irdetect.kernels.sampling.climb``;
    ``frames``, ``dts``, ``kw`` as ``_frame_blocks`` gives them)."""
    climb(frames, dts, kw["shift"], c, v, z, rows[row_order(c[rows, 1])], float(norm),
          np.array(_REFINE, np.float64), REFINE_ROUNDS, float(screen), kw["cap"])


def _three(blocks) -> tuple:
    """The evidence's blocks as the kernels take them: 3 float32 (F_j, H, W) arrays (the
    pipeline's 3 windows; fewer padded with empty blocks, more joined into one), so each
    kernel is compiled once, for one type."""
    blocks = [np.ascontiguousarray(b, dtype=np.float32) for b in blocks]
    if len(blocks) > 3:
        blocks = [np.concatenate(blocks)]
    empty = np.zeros((0,) + blocks[0].shape[1:], np.float32)
    return tuple(blocks) + (empty,) * (3 - len(blocks))


def _kernel_args(dts, shift=None, cap=None):
    """The kernels' float32 times (F,), offsets (F, 2) (zeros for None) and cap (inf for
    None)."""
    f32 = np.float32
    shift = (np.zeros((len(dts), 2), f32) if shift is None
             else np.ascontiguousarray(shift, f32))
    return np.ascontiguousarray(dts, f32), shift, f32(np.inf if cap is None else cap)


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
    return _sample_sum(frames, dts, cc, v[:, None, :], **kw), len(dts)


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
        (z - m) / max(1, s): m the median of the statistics of the parallel tracks
        c + (r cos a, r sin a), velocity v, for r in ``LOCAL_RADII`` and
        ``LOCAL_ANGLES`` angles a, and s their upper spread (``upper_sigma``): the
        track's significance against the local null distribution of track sums instead
        of against independent noise.

    Notes
    -----
    Beyond the paper. ``track_significance`` divides by sigma sqrt(F), the spread of a
    track sum over F independent frames. On real backgrounds the registered residual
    is correlated in time (clutter residue stays at its scene point for many frames):
    on the DAUB sequences the spread of track sums at random places is 2.4-6 times
    sigma sqrt(F) (simulator: 0.8-1.0), so textured ground passes ``verify`` while a
    target in a quiet patch would pass anyway. The floor 1 keeps the test no stricter
    than ``verify`` where the clutter is white noise.

    The spread is the upper one: a false alarm is a parallel track that sums high, and
    the low side is often long where the background over-estimates, above all about a
    target that the camera holds still, whose own trail in the registered background
    (dilated by ``tolerance``) sinks the tracks beside it (daub-data22-a, frames 0-35,
    a scratch measurement: sums -14 to 3.1, two-sided spread 3.6, upper 1.9). With the
    MAD of both sides that target's track stood 3.0 spreads out and was dropped.
    """
    if len(c) == 0:
        return np.zeros(0)
    med, spread = upper_sigma(local_sums(evidence, c, v))
    return (np.asarray(z, np.float64) - med) / np.maximum(spread, 1.0)


def local_sums(evidence: Evidence, c: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The statistics (``track_significance`` units) of the parallel tracks of the local
    test: shape (n, R x A), the tracks c + (r cos a, r sin a) at velocity v for r in
    ``LOCAL_RADII`` and ``LOCAL_ANGLES`` angles a (staggered by half a step per radius)."""
    a = np.arange(LOCAL_ANGLES) * (2 * np.pi / LOCAL_ANGLES)
    ring = np.concatenate([r * np.column_stack([np.cos(a + i * np.pi / LOCAL_ANGLES),
                                                np.sin(a + i * np.pi / LOCAL_ANGLES)])
                           for i, r in enumerate(LOCAL_RADII)])          # (R x A, 2)
    s, n_f = _parallel_sums(evidence, c, v, ring)
    return s.astype(np.float64) / (evidence.sigma * np.sqrt(n_f))


def _sample_sum(blocks, dts, cc, vv, shift=None, cap=None):
    """Bilinear track sums: sum_f S_f(c + v dts[f] + shift[f]) over the evidence frames,
    per hypothesis.

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
    shift : ndarray of shape (F, 2), optional
        Each frame's offset (x, y) added to the track's position (``Evidence.shift``).
    cap : float, optional
        Each frame's sample counts at most ``cap`` (``CLIP`` x the evidence's sigma).

    Returns
    -------
    ndarray of float32, shape (n, hyp)

    Notes
    -----
    The compiled ``irdetect.kernels.sampling.track_sums``: positions outside a frame take
    its border pixels' values (``cv2.BORDER_REPLICATE``).
    """
    f32 = np.float32
    n, hyp = cc.shape[:2]
    total = np.zeros((n, hyp), f32)
    if n == 0 or hyp == 0:
        return total
    c = np.asarray(cc, f32)
    v = np.asarray(vv, f32)
    dts, shift, cap = _kernel_args(dts, shift, cap)
    y0 = np.ascontiguousarray(c[..., 1])
    track_sums(_three(blocks), dts, shift, np.ascontiguousarray(c[..., 0]), y0,
               np.ascontiguousarray(v[..., 0]), np.ascontiguousarray(v[..., 1]), cap,
               row_order(y0[:, 0]), total)
    return total


def _grid_sums(blocks, dts, c, v, leads, shift, cap):
    """Nearest-pixel track sums of the coarse stage: for each lead, the 3 x 3 grid of 1 px
    around c + v lead at velocity v; (n, len(leads) x 9) float32 in the order of
    ``np.tile(_GRID, (len(leads), 1))`` (the compiled
    ``irdetect.kernels.sampling.patch_sums``; ``blocks``, ``dts``, ``shift``, ``cap`` as
    ``_frame_blocks`` gives them)."""
    f32 = np.float32
    total = np.zeros((len(c), len(leads) * len(_GRID)), f32)
    at = (c[:, None, :] + v[:, None, :] * np.asarray(leads, np.float64)[None, :, None]
          ).astype(f32)                                            # (n, leads, 2)
    vx, vy = (np.ascontiguousarray(v[:, i], f32) for i in (0, 1))
    y0 = np.ascontiguousarray(at[..., 1])
    patch_sums(blocks, dts, shift, np.ascontiguousarray(at[..., 0]), y0, vx, vy, cap,
               row_order(y0[:, 0]), total)
    return total


def verify_tracks(evidence: Evidence, points: np.ndarray, *, verify: float = 6.5,
                  verify_local: float = 3.5, screen: float = 0.4):
    """The chains that pass the verification, with their verified tracks.

    Parameters
    ----------
    evidence : Evidence
    points : ndarray of shape (n, 3, 2)
        (x, y) px of each chain's 3 fused points, at ``evidence.times``.
    verify : float
        ``track_significance`` must reach it (noise sigmas of a track sum, > 0).
    verify_local : float
        ``local_significance`` must reach it (0 = no local test).
    screen : float
        Chains whose coarse statistic is under ``screen`` x ``verify`` are not refined.

    Returns
    -------
    keep : ndarray of int64 (m,)
        Rows of ``points`` that pass, in order.
    z : ndarray (m,)
        Their statistics.
    c, v : ndarray (m, 2)
        Their tracks: position (x, y) at the evidence's middle frame, velocity px/frame.
    """
    z, c, v = track_significance(evidence, points, screen=screen * verify)
    keep = np.flatnonzero(z >= verify)
    if len(keep) and RING_RATIO > 0:
        keep = keep[ring_significance(evidence, c[keep], v[keep]) <= RING_RATIO]
    if len(keep) and verify_local > 0:
        keep = keep[local_significance(evidence, c[keep], v[keep], z[keep]) >= verify_local]
    return keep, z[keep], c[keep], v[keep]
