"""The per-frame path: tracks from each frame's CFAR peaks, initiated like radar scans.

Every frame is one scan of measurements (``irdetect.peaks``: the local maxima of the
matched, standardised residual at or above the CFAR level), in scene coordinates (image
minus the camera's offset, ``/camera``), and each window of frames (the combined-frame
path's windows, so both paths report per window) is initiated by M-of-N logic
(``irdetect.initiate``, method ``mn-logic``) with the sensor model the run derives: the
position error ``sigma`` (px) and the speed range up to ``max_speed`` px/frame against the
scene. A window's track is kept when

1. it moves by more than its position error over the window (displacement >= 3 sqrt(2)
   sigma), both against the scene and in the image: structure that stays put in the
   scene (which the suppressor's background leaves as residue) or in the image (the
   sensor's fixed pattern, a border artefact under a moving camera) is not this path's,
   and a target the camera holds still is the combined-frame path's to judge;
2. clutter of the density measured around it would make at most ``false_tracks`` x M
   chains as good anywhere in the frame (the scans clutter test of
   ``irdetect.initiate.clutter`` with the density of peaks within ``max_speed`` px of the
   track: E = H J min_j B(n_j; M, p(g_j)));
3. if it moves slower than ``clutter_speed`` against the scene, its score, the median
   local SNR of its hits, reaches the level clutter of this sequence reaches
   ``false_tracks`` times per frame (``irdetect.operating.tail_threshold``, fitted to the
   scores of the tracks that stay put in the scene: they are clutter by 1's definition,
   and a moving target cannot be among them). Structure fixed in the scene seen through
   the camera's registration error or parallax, or a peak sliding along an edge, moves
   slowly against the scene (0.4-1.4 px/frame on the real istd640 clips) and passes
   tests 1 and 2 on its persistence; a target faster than that is judged by its chain
   (test 2) alone: at the level of the brightest static residue a target no brighter
   than the clouds it crosses was lost however straight its 12 hits
   (docs/detection.md, "The per-frame path").

When 5 % of the frames or more repeat the frame before them exactly (``/camera``'s
``repeated``: a frame-rate conversion, ``irdetect.repeats``), the repeats are no scans: the
chains run on the new frames' clock, in which the target moves evenly, and their
velocities are given back per input frame.

Coordinates: x = column, y = row, px; time in frames.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from irdetect import tables
from irdetect.initiate import camera_at, initiate_points
from irdetect.initiate.clutter import LEVELS, chain_expectation, hypotheses
from irdetect.operating import tail_threshold
from irdetect.repeats import is_conversion

#: the CV check's gate in sigmas (the scans default)
GATE = 3.0


def frame_tracks(peaks: np.ndarray, camera: np.ndarray, starts, length: int, *,
                 shape: tuple[int, int], n_frames: int, level: float, false_rate: float = 1.0,
                 sigma: float = 1.0,
                 max_speed: float = 16.0, false_tracks: float = 0.001, confirm_m: int = 3,
                 confirm_n: int = 4, clutter_speed: float = 1.5) -> np.ndarray:
    """The per-frame path's tracks, one set per window of frames.

    Parameters
    ----------
    peaks : structured ndarray
        ``irdetect.tables.FRAME_DETECTION`` rows of the whole sequence.
    camera : structured ndarray
        ``irdetect.tables.CAMERA`` rows (one per frame; zeros for a still camera), their
        ``repeated`` frames no scans.
    starts : array_like of int
        First frame of every window; window k covers [starts[k], starts[k] + length).
    length : int
        Frames per window (M).
    shape : (int, int)
        Frame (H, W).
    n_frames : int
        Frames of the sequence (T).
    level : float
        The CFAR level the peaks were found at (the floor of the score threshold).
    false_rate : float
        The peaks per frame white noise gives at ``level``: the clutter density is at
        least ``false_rate`` / (H W) (a sparse neighbourhood measures no density at all).
    sigma : float
        Position error of a peak, px (> 0).
    max_speed : float
        Largest speed against the scene, px/frame (> 0).
    false_tracks : float
        Clutter tracks per frame the operating point allows (> 0).
    confirm_m, confirm_n : int
        M-of-N logic: ``confirm_m`` hits within the first ``confirm_n`` frames.
    clutter_speed : float
        px/frame against the scene: slower tracks must reach the score level of test 3
        (>= 0; inf: every track, the design before).

    Returns
    -------
    structured ndarray
        ``irdetect.tables.FRAME_TRACK`` rows, ``kept`` marking those that pass (module
        notes), in window order.
    """
    for name, value in (("sigma", sigma), ("max_speed", max_speed),
                        ("false_tracks", false_tracks)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive number, got {value!r}")
    if not clutter_speed >= 0:
        raise ValueError(f"clutter_speed must be a number >= 0, got {clutter_speed!r}")
    floor = false_rate / (float(shape[0]) * float(shape[1]))
    clock = new_frame_clock(camera, n_frames)
    parts = [_window_tracks(peaks, camera, clock, int(s), int(length), k, shape, sigma,
                            max_speed, false_tracks, confirm_m, confirm_n, floor)
             for k, s in enumerate(starts)]
    out = np.concatenate(parts) if parts else tables.empty(tables.FRAME_TRACK)
    threshold = tail_threshold(out["score"][~out["moving"]], n_frames, false_tracks, level)
    slow = np.hypot(out["svx"], out["svy"]) < clutter_speed
    out["kept"] &= ~slow | (out["score"] >= threshold)
    return out


def new_frame_clock(camera: np.ndarray, n_frames: int) -> np.ndarray:
    """(T,) int: each frame's index among the new frames (a repeat has the index of the
    frame it repeats; ``camera``'s ``repeated``, frames without a row counted new) when
    they are a frame-rate conversion's (``irdetect.repeats.is_conversion``);
    0 .. T-1 otherwise (a recording's lone repeat is a frame like any other, as in
    ``irdetect track``)."""
    repeated = np.zeros(n_frames, bool)
    inside = camera["frame"] < n_frames
    repeated[camera["frame"][inside]] = camera["repeated"][inside]
    if not is_conversion(int(repeated.sum()), n_frames):
        return np.arange(n_frames)
    return np.cumsum(~repeated) - 1


def _window_tracks(peaks, camera, clock, start, length, k, shape, sigma, max_speed,
                   false_tracks, confirm_m, confirm_n, floor) -> np.ndarray:
    """``frame_tracks`` of one window, ``kept`` by tests 1 and 2."""
    sel = np.flatnonzero((peaks["frame"] >= start) & (peaks["frame"] < start + length))
    p = peaks[sel]
    window = clock[start:start + length]
    # time u counts new frames: the peaks of a repeat are no scan
    f = p["frame"]
    p = p[(f == 0) | (clock[f] != clock[np.maximum(f - 1, 0)])]
    f = p["frame"]
    u = clock[f]
    if np.unique(u).size < 2:
        return tables.empty(tables.FRAME_TRACK)
    off = camera_at(camera, f)
    sx, sy = p["x"] - off[:, 0], p["y"] - off[:, 1]
    rows, members = initiate_points(sx, sy, u.astype(float), u, method="mn-logic",
                                    sigma=sigma, v_max=max_speed, gate=GATE,
                                    confirm_m=confirm_m, confirm_n=confirm_n)
    n = len(rows)
    if not n:
        return tables.empty(tables.FRAME_TRACK)
    out = tables.from_columns(tables.FRAME_TRACK, n=n)
    mid = start + (length - 1) / 2.0
    t0 = rows["t_start"]
    u_mid = np.interp(mid, np.arange(start, start + len(window)), window)
    scene_x = rows["x0"] + rows["vx"] * (u_mid - t0)
    scene_y = rows["y0"] + rows["vy"] * (u_mid - t0)
    at = camera_at(camera, np.array([start, mid, start + length - 1.0]))
    out["x"], out["y"] = scene_x + at[1, 0], scene_y + at[1, 1]
    # new frames per input frame over the window (1 without repeats), and the camera's
    # image velocity per new frame
    scale = (window[-1] - window[0]) / (length - 1.0) if length > 1 else 1.0
    cam_v = (at[2] - at[0]) / max(1.0, window[-1] - window[0])
    out["svx"], out["svy"] = rows["vx"] * scale, rows["vy"] * scale
    out["vx"], out["vy"] = (rows["vx"] + cam_v[0]) * scale, (rows["vy"] + cam_v[1]) * scale
    out["combined_frame"] = k
    out["frame_start"], out["frame_end"] = start, start + length - 1
    out["n_points"] = rows["n_points"]
    # the hits padded to (n, K): their scores and normalised residuals to the CV fit
    cnt = np.array([m.size for m in members])
    K = int(cnt.max())
    idx = np.zeros((n, K), np.int64)
    pad = np.arange(K)[None, :] < cnt[:, None]
    idx[pad] = np.concatenate(members)
    score = np.where(pad, p["score"][idx], np.nan)
    out["score"] = np.nanmedian(score, axis=1)
    dt = u[idx] - t0[:, None]
    ex = sx[idx] - (rows["x0"][:, None] + rows["vx"][:, None] * dt)
    ey = sy[idx] - (rows["y0"][:, None] + rows["vy"][:, None] * dt)
    e = np.where(pad, np.hypot(ex, ey) / sigma, np.inf)
    span = rows["t_end"] - rows["t_start"]
    # moving against the scene and in the image: structure fixed in either (the scene's,
    # or the sensor's pattern under a moving camera) is not this path's
    least = GATE * math.sqrt(2.0) * sigma
    out["moving"] = np.hypot(rows["vx"], rows["vy"]) * span >= least
    in_image = np.hypot(rows["vx"] + cam_v[0], rows["vy"] + cam_v[1]) * span >= least
    scans = int(window[-1] - window[0]) + 1
    out["expectation"] = _expectation(e, rows, sx, sy, idx, pad, shape, scans, sigma,
                                      max_speed, floor)
    out["kept"] = out["moving"] & in_image & (out["expectation"] <= false_tracks * length)
    return out


def _expectation(e, rows, sx, sy, idx, pad, shape, length, sigma, max_speed, floor):
    """E of every track (``irdetect.initiate.clutter.chain_expectation``) with the clutter
    density of the peaks (not its own) within ``max_speed`` px of its fitted path, per
    frame and px^2, at least ``floor``."""
    n = len(rows)
    hits = (e[:, :, None] <= GATE * np.asarray(LEVELS)[None, None, :]).sum(axis=1)
    # the path over the window: the fit at its first and last hit, and a corridor of
    # half-width max_speed about it (area 2 R L + pi R^2)
    a = np.column_stack([rows["x0"], rows["y0"]])
    b = a + np.column_stack([rows["vx"], rows["vy"]]) * (rows["t_end"] - rows["t_start"])[:, None]
    half = 0.5 * np.hypot(*(b - a).T)
    radius = max_speed
    tree = cKDTree(np.column_stack([sx, sy]))
    near = tree.query_ball_point(0.5 * (a + b), half + radius)
    counts = np.array([len(v) for v in near])
    src = np.repeat(np.arange(n), counts)
    j = np.concatenate([np.asarray(v, np.int64) for v in near]) if counts.sum() else \
        np.zeros(0, np.int64)
    q = np.column_stack([sx[j], sy[j]])
    ab = b[src] - a[src]
    t = np.clip(((q - a[src]) * ab).sum(1) / np.maximum((ab ** 2).sum(1), 1e-12), 0.0, 1.0)
    inside = np.hypot(*(q - a[src] - t[:, None] * ab).T) <= radius
    # a track's own hits are not clutter: (track, peak) pairs as one integer key
    mine = np.repeat(np.arange(n), pad.sum(1)) * len(sx) + idx[pad]
    own = np.isin(src * len(sx) + j, mine)
    clutter = np.bincount(src[inside & ~own], minlength=n)
    area = 2.0 * radius * 2.0 * half + math.pi * radius ** 2
    density = np.maximum(clutter / (length * area), floor)
    h, w = shape
    H = hypotheses(float(h * w), float(length - 1), max_speed, GATE, np.full(n, sigma),
                   np.full(n, sigma))
    return chain_expectation(hits, length, density[:, None], np.full(n, sigma),
                             np.full(n, sigma), H,
                             GATE)
