"""Run a frame-by-frame tracker over a whole sequence, window by window."""

from __future__ import annotations

import logging
import math
from typing import Callable

import numpy as np
from tqdm import tqdm

from irdetect import tables
from irdetect.binning import Binned, binned_mask, check_bin, to_input
from irdetect.exclude import excluded, exclusion_mask
from irdetect.io.sources import FrameSource, check_values
from irdetect.peaks import STANDARDISE_ERROR, cfar_level, frame_level
from irdetect.repeats import FrameGroups, NewFrames, frame_groups
from irdetect.suppress import bright_up, is_dark
from irdetect.track.confirm import ClutterTest
from irdetect.track.detector import detector_blocks, guided_regions, peak_regions
from irdetect.track.regions import extract_regions, residual_level
from irdetect.track.seasky import find_sea_sky_line, sea_sky_band
from irdetect.track.tracker import FCMPMHTTracker, GNNTracker

log = logging.getLogger(__name__)

METHODS = ("fcm-pmht", "gnn")
REGION_SOURCES = ("detector", "tophat")
#: frames per window of the per-frame detector (its noise scale is measured per window:
#: the combined-frame path's 12, as ``irdetect process`` does)
DETECTOR_WINDOW = 12
#: the detector's regions: a grey difference counts one unit of FCM distance per this
#: fraction of the larger grey (a local SNR varies in proportion to itself)
GREY_RELATIVE = 0.5
#: px: the regions within this radius of a tentative track's predictions are its local
#: clutter (the confirmation test; the per-frame path's ``max_speed``)
CLUTTER_RADIUS = 16.0
#: px: a confirmed track that the frame's regions miss is looked for within this radius of
#: its prediction at the level ``guided_rate`` sets (``irdetect.track.detector.guided_regions``)
GUIDED_PX = 4.0
#: px: the detector's regions this large or larger are measured for their shape
#: (``min_shape``); a smaller one's second moments say little (a 1 x 2 px region has shape 0)
LINE_AREA = 6


def track(frames, sink: Callable[[np.ndarray], None] | None = None, progress: bool = False,
          suppression: dict | None = None,
          camera_sink: Callable[[np.ndarray], None] | None = None, exclude=(), *,
          method: str = "fcm-pmht", regions: str = "detector", false_rate: float = 1.0,
          psf: float = 1.0, fraction: float = 0.5, false_tracks: float = 0.001,
          sigma: float = 1.0, max_speed: float = 16.0, learn_frames: int = 12,
          motion_p: float = 0.001, clutter_speed: float = 1.5, guided_rate: float = 0.01,
          min_shape: float = 0.35, three_point: bool = True,
          sea_sky: bool = False, band_above: float = 5.0,
          band_below: float = 40.0, suppress_size: int = 15, k: float = 5.0,
          smooth: float = 1.0, tile: int = 32, min_contrast: float = 0.0,
          min_area: float = 1.0, max_area: float = 200.0,
          grey_gate: bool = False, min_grey: float = 100.0, max_grey: float = 180.0,
          max_regions: int = 200,
          frame_interval: float = 1.0, q0: float = 1e-3, r: float = 0.5,
          adaptive: bool = True, beta: float = 0.9, m: float = 2.0, gate: float = 4.0,
          w_position: float = 1.0, w_grey: float = 1.0, w_area: float = 1.0,
          w_direction: float = 1.0, grey_scale: float = 4.5, area_scale: float = 0.5,
          direction_after: int = 3, min_speed: float = 0.2, confirm_hits: int = 3,
          confirm_window: int = 30, max_misses: int = 12, max_merged: int = 150,
          merge_margin: float = 1.0, max_tracks: int = 200, init_speed: float = 2.0,
          feature_memory: float = 0.9, lost_clutter: float = 1.0,
          window: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Track targets frame by frame through a sequence (Cheng et al.).

    Parameters
    ----------
    frames : ndarray of shape (T, H, W) or FrameSource
        The sequence; anything with ``len()`` and slicing ``frames[a:b]`` -> (n, H, W).
        It is read ``window`` frames at a time, so memory does not grow with T.
    sink : callable, optional
        Called with each chunk of TRACK_POINT rows as it is released (e.g. a results
        writer's append); the returned points table is then empty.
    progress : bool
        Show a tqdm bar over frames.
    suppression : dict, optional
        Keywords of ``irdetect.suppress.suppress`` for the detector's regions (the
        ``[suppress]`` table; ``irdetect.track.detector.SUPPRESS_DEFAULTS`` otherwise);
        its ``polarity`` ``"dark"`` mirrors the frames of the top-hat regions too, and its
        ``bin`` (> 1) averages blocks of that many pixels a side first for either region
        source (``irdetect.binning``; the points, tracks and camera rows given out are in
        the input's pixels).
    camera_sink : callable, optional
        Called with the ``irdetect.tables.CAMERA`` rows (the camera's offset x, y px of
        every frame) as they are measured (the detector's regions only).
    exclude : sequence of str
        Pixels where no region is taken (``irdetect.exclude``: rectangles "X0,Y0,X1,Y1"
        or mask images of the frames' size; a burned-in overlay).
    method : {"fcm-pmht", "gnn"}
        FCM association + adaptive PMHT (:class:`FCMPMHTTracker`) or the CV Kalman + global
        nearest neighbour baseline (:class:`GNNTracker`).
    regions : {"detector", "tophat"}
        Where the regions come from: the per-frame detector of ``irdetect process``
        (``irdetect.track.detector``: suppression with the camera's motion, the PSF's
        matched filter, CFAR peaks on the local noise, each peak's half-maximum region;
        tracks in scene coordinates), or the white top-hat of
        :func:`irdetect.track.regions.extract_regions` (the ``maritime`` and ``paper``
        profiles; image coordinates, the camera taken to hold still).
    false_rate : float
        The detector's CFAR level: white-noise peaks per frame (``irdetect.peaks``).
    psf : float
        Sigma (px) of the detector's matched filter (1 px, issue 17's ``smooth``;
        ``process``'s ``combine.dp_smooth`` is 0.6 px, which puts 6 of the 17 real folders
        at the goal against 9, leave-one-out in docs/results/tracking.md).
    fraction : float
        A detector region holds the pixels around its peak at or above this fraction of
        its highest value (``irdetect.track.detector.peak_regions``).
    false_tracks : float
        Clutter tracks per frame the confirmation allows (``irdetect.track.confirm``):
        a tentative track must move against the scene, pass the scans clutter test with
        the local density and reach the score this sequence's clutter that moves as far
        reaches this often;
        0: the M-of-N rule alone (``confirm_hits`` in ``confirm_window``).
    sigma : float
        Position error of a region (px) in the confirmation's tests.
    max_speed : float
        Largest speed against the scene (px/frame) of the clutter test's hypotheses.
    learn_frames : int
        No track is confirmed before this many frames (the clutter sample of the score
        test is too young).
    motion_p : float
        A tentative track's motion must be significant at this level against the scatter
        of its own hits (``irdetect.track.confirm.still_chance``), in (0, 1]; 1: not tested.
    clutter_speed : float
        px/frame against the scene: a tentative track that passes the confirmation's
        motion and clutter tests and moves this fast or faster is no sample of the clutter
        whose scores set the level a track must reach (``irdetect.track.confirm``: a target
        that failed only that level raised it for the next; ``process``'s per-frame path
        judges such tracks by their chain alone too); inf: every track.
    guided_rate : float
        The detector's regions: a confirmed track that no region of the frame is within
        ``GUIDED_PX`` px of is looked for there at the level white noise reaches this often
        per frame in that disc (3.6 local sigmas at 0.01, against the frame's 4.2-4.6 at
        ``false_rate`` 1); what is found there feeds tracks but starts none. 0: off (the
        frame's level alone, as before).
    min_shape : float
        The detector's regions of ``LINE_AREA`` px or more whose shape (sqrt(l2 / l1) of
        their second moments, ``irdetect.track.detector.peak_regions``) is under this are
        lines, not points (an edge's residue under a pan, a roof's rim), and are dropped: a
        point source's half-maximum region is round (0.9-1), two that touch (a merge) make one
        of 0.47 or more (PSF sigma 1 px, until their regions part); 0: every region kept.
    three_point : bool
        With the clutter test's confirmation (``false_tracks`` > 0): also start a track
        from three regions of three frames in a line, up to ``max_speed`` px/frame apart
        (``irdetect.track.tracker``, three-point starts): a target faster than a new
        track's gate (``init_speed``) leaves a one-hit track in each frame (a fast target
        whose camera cannot be measured: bench_unseen's scenes 41, 60, 70 at 6-12 px/frame
        in the image, MOTA 0.38-0.51 without, 0.995-1.000 with). Such tracks are tested
        as any other but are no sample of the clutter (their extra hits' scores raised its
        level over slow targets). False: one-region starts alone (the paper's design).
    sea_sky : bool
        Find the sea-sky line in every frame and search only the band from ``band_above``
        pixels above it to ``band_below`` pixels below it (maritime scenes; off for sky or
        ground scenes). A frame without a detectable horizon is searched whole.
    suppress_size, k, smooth, tile, min_contrast, min_area, max_area, min_grey, max_grey,
    max_regions
        Region extraction, see :func:`irdetect.track.regions.extract_regions`; the grey
        interval [min_grey, max_grey] applies only with ``grey_gate`` (the paper's). Regions up to
        2 x ``max_area`` are kept, because two merged targets make one region of up to twice
        the area; those larger than ``max_area`` feed existing tracks but start none. The
        defaults hold for any dtype, background and noise level: the top-hat residual
        smoothed by a 1-px Gaussian (the matched filter of a small PSF), thresholded at 5
        robust sigmas of its own noise measured per 32-px tile, no grey gate, areas
        2-200 px. Sea scenes, whose waves and glints sit at the targets' scale, take the
        ``maritime`` profile (sea-sky band, unsmoothed, one level per frame, 5.5 sigmas,
        5 px); the paper's absolute gates are the ``paper`` profile (data/profiles/). With
        the detector's regions only the area and grey gates apply (grey: local SNR), and
        ``tile`` sets the detector's noise tiles.
    grey_scale : float
        Grey difference counted as one unit of FCM distance, in robust sigmas of the
        first frame's suppressed residual (``irdetect.track.regions.residual_level``),
        so it means the same on any sensor (4.5 sigmas: the paper's 20 grey levels on
        the harbour scene, whose residual sigma is 4.4).
    frame_interval, q0, r, adaptive, beta, m, gate, w_position, w_grey, w_area, w_direction,
    area_scale, direction_after, min_speed, confirm_hits, confirm_window,
    max_misses, max_merged, merge_margin, max_tracks, init_speed, feature_memory,
    lost_clutter
        Tracker parameters, see :class:`irdetect.track.tracker.FCMPMHTTracker` (the GNN
        baseline ignores the FCM, adaptive-noise and merge ones).
    window : int
        Frames read at a time (the top-hat regions; the detector reads 12-frame windows).

    Returns
    -------
    points : ndarray of dtype TRACK_POINT
        One row per confirmed track per frame (x = column, y = row, pixels; vx, vy in pixels
        per frame interval), including frames coasted through between two detections.
    tracks : ndarray of dtype TRACK
        One summary row per confirmed track: the least-squares line (rho, theta) and
        velocity through its points, first / last frame, point count, and score = share of
        its points that were measured rather than predicted.

    Examples
    --------
    >>> from irdetect.simulate.harbour import simulate_harbour
    >>> frames, truth = simulate_harbour(n_frames=60, rng=1)
    >>> points, tracks = track(frames, sea_sky=True, regions="tophat", false_tracks=0.0,
    ...                        confirm_window=5)          # the maritime profile's regions
    >>> len(tracks) >= 3
    True
    >>> from irdetect.simulate import simulate
    >>> frames, truth = simulate("wan2008", snr=6, n_targets=1, n_frames=40, rng=1)
    >>> points, tracks = track(frames)                     # the per-frame detector's regions
    >>> len(tracks)
    1
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    if regions not in REGION_SOURCES:
        raise ValueError(f"regions must be one of {REGION_SOURCES}, got {regions!r}")
    if not 0 <= min_area <= max_area:
        raise ValueError(f"need 0 <= min_area <= max_area, got {min_area!r}, {max_area!r}")
    if window < 1:
        raise ValueError(f"window must be >= 1, got {window!r}")
    if len(frames.shape) != 3:
        raise ValueError(f"frames must be (T, H, W), got shape {frames.shape}")
    n, h, w = frames.shape
    # oversampled footage is binned first (``suppress.bin``, ``irdetect.binning``); the
    # tables given out are in the input's pixels
    factor = check_bin((suppression or {}).get("bin", 1))
    excluded_px = binned_mask(exclusion_mask(exclude, (h, w)), factor)
    # a frame-rate conversion's repeated frames are no observations: the tracker runs on
    # the new frames, and each repeat takes the points of the frame it repeats
    groups = frame_groups(frames)
    if groups.n_new < n:
        if groups.n_new > 1:        # a still image is ``flat_frames``' to report
            log.info("%d of %d frames repeat the frame before them exactly (a frame-rate "
                     "conversion): tracked on the %d new frames (docs/tracking.md)",
                     n - groups.n_new, n, groups.n_new)
        frames = NewFrames(frames, groups)
        n = groups.n_new
    if factor > 1:
        frames = Binned(frames, factor)
        n, h, w = frames.shape
    if not grey_scale > 0:
        raise ValueError(f"grey_scale must be > 0, got {grey_scale!r}")
    if not (np.isfinite(false_tracks) and false_tracks >= 0):
        raise ValueError(f"false_tracks must be a number >= 0, got {false_tracks!r}")
    if not (np.isfinite(psf) and psf >= 0):
        raise ValueError(f"psf must be a number >= 0, got {psf!r}")
    if int(learn_frames) != learn_frames or learn_frames < 0:
        raise ValueError(f"learn_frames must be an int >= 0, got {learn_frames!r}")
    if not 0 < fraction <= 1:
        raise ValueError(f"fraction must lie in (0, 1], got {fraction!r}")
    detector = regions == "detector"
    # the top-hat regions take the frames mirrored as the detector's suppression does
    dark = is_dark((suppression or {}).get("polarity", "bright"))
    level, guided = 0.0, None
    if detector:
        if tile < 1 or int(tile) != tile:
            raise ValueError(f"tile must be an int >= 1 with regions = 'detector', got {tile!r}")
        level = frame_level((h, w), false_rate)         # checks false_rate
        if not 0 <= min_shape <= 1:
            raise ValueError(f"min_shape must lie in [0, 1], got {min_shape!r}")
        if not (np.isfinite(guided_rate) and guided_rate >= 0):
            raise ValueError(f"guided_rate must be a number >= 0, got {guided_rate!r}")
        disc = max(1, int(math.pi * GUIDED_PX ** 2))
        guided = (min(level, cfar_level(disc, guided_rate, STANDARDISE_ERROR))
                  if 0 < guided_rate < disc else None)
        # the detector's grey is a local SNR: its unit is one matched-filter sigma
        grey_levels = grey_scale
    else:
        # grey differences in sigmas of the first frame's residual: measured once per run
        s0 = residual_level(bright_up(frames[0]) if dark else np.asarray(frames[0]),
                            suppress_size)[1] if n else 1.0
        grey_levels = grey_scale * (s0 if np.isfinite(s0) and s0 > 0 else 1.0)
    test = None
    if false_tracks > 0:
        test = ClutterTest((h, w), false_tracks=false_tracks, sigma=sigma,
                           max_speed=max_speed, radius=CLUTTER_RADIUS,
                           floor=false_rate / float(h * w) if detector else 0.0,
                           window=confirm_window, score_floor=level,
                           learn=learn_frames, motion_p=motion_p,
                           clutter_speed=clutter_speed)
    common = dict(frame_interval=frame_interval, q0=q0, r=r, gate=gate,
                  confirm_hits=confirm_hits, confirm_window=confirm_window,
                  max_misses=max_misses, max_tracks=max_tracks, init_speed=init_speed,
                  feature_memory=feature_memory, max_birth_area=max_area, confirm=test,
                  lost_clutter=lost_clutter,
                  max_speed=max_speed if three_point and test is not None else 0.0)
    if method == "gnn":
        tracker = GNNTracker(**common)
    else:
        tracker = FCMPMHTTracker(
            adaptive=adaptive, beta=beta, m=m, w_position=w_position, w_grey=w_grey,
            w_area=w_area, w_direction=w_direction, grey_scale=grey_levels,
            area_scale=area_scale, direction_after=direction_after, min_speed=min_speed,
            max_merged=max_merged, merge_margin=merge_margin,
            grey_relative=GREY_RELATIVE if detector else 0.0, **common)
    region_kw = dict(suppress_size=suppress_size, k=k, smooth=smooth, tile=tile,
                     min_contrast=min_contrast, min_area=min_area, max_area=2 * max_area,
                     min_grey=min_grey if grey_gate else -np.inf,
                     max_grey=max_grey if grey_gate else np.inf, max_regions=max_regions)
    if sea_sky and (band_above < 0 or band_below < 0):
        raise ValueError(f"band_above and band_below must be >= 0, got "
                         f"{band_above!r}, {band_below!r}")
    if detector:
        if sea_sky:
            raise ValueError("sea_sky needs regions = 'tophat' (the maritime profile)")
        extract_regions(np.zeros((8, 8), np.float32), **region_kw)   # names bad gates
    chunks: list[np.ndarray] = []
    give = sink if sink is not None else chunks.append

    def emit(rows):
        give(to_input("track_points", groups.expand(rows), factor))
    offsets = np.zeros((n, 2))
    n_regions = 0

    def blocks():
        """(first frame, frames' regions source, camera offsets, gains) per block."""
        if detector:
            yield from detector_blocks(frames, length=DETECTOR_WINDOW, psf=psf, tile=int(tile),
                                       suppression=suppression)
            return
        for start in range(0, n, window):
            block = np.asarray(frames[start:start + window])
            if isinstance(frames, FrameSource):     # a file's frames must be finite
                check_values(block, start, frames.path)
            yield start, bright_up(block) if dark else block, None, None

    with tqdm(total=n, unit="frame", desc="track", disable=not progress) as bar:
        for start, block, off, gains in blocks():
            if off is not None:
                offsets[start:start + len(block)] = off
                if camera_sink is not None:
                    camera_sink(to_input("camera", groups.expand(tables.from_columns(
                        tables.CAMERA, frame=np.arange(start, start + len(block)),
                        dx=off[:, 0], dy=off[:, 1], gain=gains[:, 0], level=gains[:, 1]),
                        velocity=()), factor))
            out = []
            for j, frame in enumerate(block):
                seeds = None
                if detector:
                    regs = _gated(peak_regions(frame, level, fraction=fraction,
                                               max_peaks=max_regions), region_kw, min_shape)
                    o = offsets[start + j]
                    if guided is not None:
                        more = _gated(guided_regions(frame, regs, tracker.predicted() + o,
                                                     guided, radius=GUIDED_PX,
                                                     fraction=fraction),
                                      region_kw, min_shape)
                        seeds = np.arange(len(regs) + len(more)) < len(regs)
                        regs = np.concatenate([regs, more])
                    if excluded_px is not None:
                        kept = ~excluded(excluded_px, regs["x"], regs["y"])
                        regs, seeds = regs[kept], None if seeds is None else seeds[kept]
                    regs = _to_scene(regs, o)
                else:
                    mask = None
                    if sea_sky:
                        mask = sea_sky_band(find_sea_sky_line(frame), (h, w),
                                            above=band_above, below=band_below)
                    regs = extract_regions(frame, mask=mask, **region_kw)
                    regs = regs[~excluded(excluded_px, regs["x"], regs["y"])]
                    o = (0.0, 0.0)
                n_regions += len(regs)
                out.append(tracker.step(start + j, regs, (h, w), o, seeds))
            pts = np.concatenate(out) if out else tables.empty(tables.TRACK_POINT)
            if len(pts) and detector:
                # scene -> image coordinates at each point's frame
                pts["x"] += offsets[pts["frame"], 0]
                pts["y"] += offsets[pts["frame"], 1]
            if len(pts):
                emit(pts)
            bar.update(len(block))
    summary = to_input("tracks", _input_frames(tracker.finish(), groups), factor)
    log.debug("tracked %d frames: %d regions, %d confirmed tracks", n, n_regions, len(summary))
    points = np.concatenate(chunks) if chunks else tables.empty(tables.TRACK_POINT)
    return points, summary


def _input_frames(summary: np.ndarray, groups: FrameGroups) -> np.ndarray:
    """TRACK rows whose frames count new frames (``irdetect.repeats``) in input frames:
    ``frame_start`` the first showing its first point, ``frame_end`` the last showing its
    last, ``n_points`` the input frames between, velocities per input frame."""
    if not len(summary) or groups.n_new == groups.n_input:
        return summary
    out = summary.copy()
    out["frame_start"] = groups.first(summary["frame_start"])
    out["frame_end"] = groups.last(summary["frame_end"])
    out["n_points"] = out["frame_end"] - out["frame_start"] + 1
    out["vx"] *= groups.scale
    out["vy"] *= groups.scale
    return out


def _gated(regs: np.ndarray, kw: dict, min_shape: float) -> np.ndarray:
    """The detector's regions within the area gate [min_area, max_area] and the grey
    interval [min_grey, max_grey] (grey: local SNR), less the lines (``min_shape``)."""
    keep = ((regs["area"] >= kw["min_area"]) & (regs["area"] <= kw["max_area"])
            & (regs["grey"] >= kw["min_grey"]) & (regs["grey"] <= kw["max_grey"])
            & ((regs["area"] < LINE_AREA) | (regs["shape"] >= min_shape)))
    return regs[keep]


def _to_scene(regs: np.ndarray, offset) -> np.ndarray:
    """Regions in scene coordinates: image position minus the camera's offset (x, y px;
    bounding boxes by the offset rounded to whole px)."""
    if not len(regs) or not (offset[0] or offset[1]):
        return regs
    regs = regs.copy()
    regs["x"] -= offset[0]
    regs["y"] -= offset[1]
    regs["bx"] -= int(round(offset[0]))
    regs["by"] -= int(round(offset[1]))
    return regs
