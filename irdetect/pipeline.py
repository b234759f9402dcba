"""The detection pipeline: the only module that knows the order of the stages.

frames -> suppress -> combine (one window at a time) -> detect -> fuse -> correlate over
the last 3 combined frames (chains verified by a matched filter over their frames) ->
confirmed detections -> track initiation.

The sequence is streamed: one window of frames (plus the ``history`` frames the temporal
suppressor needs) is in memory at a time, and only the fused points and the matched
residual frames of the last 3 combined frames are kept for correlation, so memory is
bounded by the window, not the sequence length. A combined frame's candidates are final (and written) once the segment
over it and the next two combined frames has been searched.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import threading
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np
from scipy.spatial import cKDTree

from irdetect import tables
from irdetect.camera import CameraMotion
from irdetect.combine import combine, frames_needed, window_starts
from irdetect.config import ProcessConfig, to_json
from irdetect.correlate import Correlation, correlate
from irdetect.detect import detect
from irdetect.errors import InputError, refused_settings
from irdetect.fuse import fuse
from irdetect.io.sources import FrameSource
from irdetect.suppress import future_frames, past_frames, suppress
from irdetect.verify import DP_LEADS, Evidence, matched_frame, noise_level, standardise

log = logging.getLogger(__name__)

#: combined frames the correlation needs
N_CORRELATE = 3
_TIMINGS_LOCK = threading.Lock()


#: the shortest combined frame a short sequence is run with: 3 of them, 12 frames, is the
#: shortest sequence ``irdetect process`` takes
MIN_LENGTH = 4
#: the largest integer setting (a size in px or frames: a combined frame's length, a
#: window, a tile) a configuration may give; 1000 frames already smear any moving target
MAX_LENGTH = 1000
#: the largest magnitude of a real-valued setting, and 1 / it the smallest but 0
#: (thresholds, sigmas, speeds: beyond any; float32 maps overflow near 3e38 and a cell of
#: 1e-236 px overflowed the Minkowski distance)
MAX_SETTING = 1e9
#: frames narrower or lower than this are refused (``check_frames``)
MIN_SIDE = 8
#: memory per pixel of a window's frames a run holds at once, with margin: raw and float
#: frames, suppressed frames, the combined frames' maps (peak 364 MB at 640x512 with 12
#: frames, docs/results/throughput.md, of which ~150 MB are the libraries)
WINDOW_BYTES_PER_PIXEL = 64


def min_frames(config: ProcessConfig | None = None) -> int:
    """Frames needed for 3 combined frames of the configured length (36 with the
    defaults); shorter sequences run with shorter combined frames (``fit_config``)."""
    c = (config or ProcessConfig()).combine
    return frames_needed(N_CORRELATE, length=c.length, step=c.step)


def fit_config(config: ProcessConfig | None, n_frames: int) -> ProcessConfig:
    """The configuration a sequence of ``n_frames`` frames runs with.

    ``config`` itself when its 3 combined frames fit (``min_frames``). A shorter sequence
    runs with the longest combined frames that fit, down to ``MIN_LENGTH`` frames: length
    L' and step max(1, round(step L' / L)) scaled together (30 frames with the defaults:
    3 combined frames of 10 frames).

    Raises
    ------
    ValueError
        Fewer frames than 3 combined frames of ``MIN_LENGTH`` frames need (or of the
        configured length when it is shorter); the message says how many are needed.
    """
    config = config or ProcessConfig()
    c = config.combine
    if n_frames >= min_frames(config):
        return config
    for length in range(c.length - 1, min(MIN_LENGTH, c.length) - 1, -1):
        step = max(1, round(c.step * length / c.length))
        if frames_needed(N_CORRELATE, length=length, step=step) <= n_frames:
            return dataclasses.replace(
                config, combine=dataclasses.replace(c, length=length, step=step))
    need = frames_needed(N_CORRELATE, length=min(MIN_LENGTH, c.length),
                         step=max(1, round(c.step * min(MIN_LENGTH, c.length) / c.length)))
    raise ValueError(f"the sequence has {n_frames} frames; detection needs at least {need} "
                     f"(3 combined frames of at least {min(MIN_LENGTH, c.length)} frames)")


def iter_results(frames, config: ProcessConfig | None = None, *,
                 progress: bool = False, workers: int = 1,
                 timings: dict | None = None) -> Iterator[dict]:
    """Run the front end over a sequence, yielding results as combined frames complete.

    Parameters
    ----------
    frames : ndarray of shape (T, H, W) or irdetect.io.FrameSource
        Anything with ``len()``, ``.shape`` and slicing ``frames[a:b]`` -> (b - a, H, W).
    config : ProcessConfig, optional
        Stage parameters (defaults when None).
    progress : bool
        Show a tqdm bar over frames.
    workers : int
        Threads (>= 1; OpenCV and numpy release the GIL) that run suppression,
        combination, detection and fusion of the next windows and the correlation (with
        its verification) of each window triple at once; reading, confirming and
        emitting stay in order on the calling thread, so the results do not depend on
        it. Each thread holds its own copy of a window's raw frames.
    timings : dict, optional
        When given, seconds spent per stage are added to it under ``read``, ``suppress``,
        ``combine``, ``detect``, ``fuse``, ``correlate`` (summed over threads).

    Yields
    ------
    dict
        ``{"candidates": CANDIDATE rows, "detections": DETECTION rows,
        "segments": SEGMENT rows, "camera": CAMERA rows}`` for one combined frame, in
        order; the segments are those starting in that combined frame, the camera rows
        those of its frames not given before (``irdetect.camera``; zeros unless
        ``suppress.method`` is ``auto`` or ``registered``).

    Raises
    ------
    ValueError
        Fewer frames than 3 combined frames of ``MIN_LENGTH`` frames need; the message says
        how many are needed. Sequences shorter than ``min_frames`` run with shorter
        combined frames (``fit_config``).
    """
    config = config or ProcessConfig()
    shape = tuple(frames.shape)
    if len(shape) != 3:
        raise ValueError(f"frames must have shape (T, H, W), got {shape}")
    n_frames = shape[0]
    config = fit_config(config, n_frames)
    cc = config.combine
    if int(workers) != workers or workers < 1:
        raise ValueError(f"workers must be an integer >= 1, got {workers!r}")
    starts = window_starts(n_frames, length=cc.length, step=cc.step)
    params = _StageParams(config)
    # the first window(s) look ahead: their first frames have no past (``lead_in``)
    ahead = [future_frames(start=int(s), stop=int(s) + cc.length, **params.suppress)
             for s in starts]
    reader = _Reader(frames, past_frames(**params.suppress), cc.length, max(ahead),
                     camera=config.suppress.method in ("auto", "registered"))
    pool = ThreadPoolExecutor(int(workers)) if workers > 1 else None
    fronts: deque = deque()      # windows read and submitted, in order
    pending: deque = deque()
    segment_id = 0
    bar = _bar(n_frames, progress)

    def submit(k: int):
        t0 = time.perf_counter()
        s = int(starts[k])
        block, previous = reader.read(s, s + cc.length + ahead[k])
        camera = reader.offsets[s - len(previous):s + len(block)]
        block, following = block[:cc.length], block[cc.length:]
        previous = previous if len(previous) else None
        following = following if len(following) else None
        if pool is None:
            _lap(timings, "read", t0)
            return _Ready(_front(block, previous, params, timings, following, camera))
        # the reader's buffer is reused: the thread gets its own copy
        block, camera = block.copy(), camera.copy()
        previous = None if previous is None else previous.copy()
        following = None if following is None else following.copy()
        _lap(timings, "read", t0)
        return pool.submit(_front, block, previous, params, timings, following, camera)

    corrs: deque = deque()       # correlations of window triples submitted, in order
    first = 0                    # the oldest pending window

    def take() -> dict:
        """Confirm the oldest triple's points by its segments; emit its first window."""
        nonlocal segment_id, first
        corr = corrs.popleft().result()
        segments = corr.segments
        segments["combined_frame"] = first
        segments["segment_id"] = np.arange(segment_id, segment_id + len(segments))
        segment_id += len(segments)
        for i, p in enumerate(list(pending)[:N_CORRELATE]):
            p.confirm(corr.index[:, i], segments, corr.positions[:, i])
        first += 1
        done = pending.popleft()
        return with_camera(done.emit(segments), done.start + cc.length)

    camera_done = 0              # frames whose /camera rows were emitted

    def with_camera(chunk: dict, end: int) -> dict:
        """The chunk of one window with the /camera rows of its frames up to ``end``."""
        nonlocal camera_done
        f = np.arange(camera_done, max(end, camera_done))
        chunk["camera"] = tables.from_columns(tables.CAMERA, frame=f, dx=reader.offsets[f, 0],
                                              dy=reader.offsets[f, 1])
        camera_done = end
        return chunk

    try:
        submitted = 0
        for k, s in enumerate(starts):
            while submitted < len(starts) and len(fronts) < (1 if pool is None else workers):
                fronts.append(submit(submitted))
                submitted += 1
            cand, n_pixels, matched = fronts.popleft().result()
            cand["frame_start"], cand["frame_end"] = s, s + cc.length - 1
            cand["combined_frame"] = k
            pending.append(_Pending(cand, cc.length if cc.projection == "dp" else 0,
                                    matched, int(s), config.correlate.tolerance,
                                    reader.offsets[s:s + cc.length].copy()))
            log.debug("combined frame %d (frames %d-%d): %d candidate pixels, %d fused points",
                      k, s, s + cc.length - 1, n_pixels, len(cand))
            if k >= N_CORRELATE - 1:
                # windows k-2, k-1, k: with a pool their correlation runs beside the next
                # windows' front end; the results are taken up in order
                triple = list(pending)[-N_CORRELATE:]
                if pool is None:
                    corrs.append(_Ready(_correlate(triple, cc, params, timings)))
                else:
                    corrs.append(pool.submit(_correlate, triple, cc, params, timings))
            while len(corrs) > (0 if pool is None else workers):
                yield take()
            if bar is not None:
                bar.update(int(min(starts[k + 1] if k + 1 < len(starts) else n_frames,
                                   n_frames) - bar.n))
        while corrs:
            yield take()
        while pending:
            done = pending.popleft()
            yield with_camera(done.emit(tables.empty(tables.SEGMENT)), done.start + cc.length)
    finally:
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)
        if bar is not None:
            bar.close()


def _correlate(triple, cc, params: "_StageParams", timings: dict | None):
    """The correlation of 3 pending windows (``correlate`` with their evidence), per band:
    the paper's band in image coordinates, the fast band's points, tracks and evidence
    in scene coordinates (image minus the camera's offset). Returns one Correlation
    whose rows index the windows' whole tables and whose positions are image
    coordinates."""
    t0 = time.perf_counter()
    evidence = _evidence(triple, cc)
    parts = [_band(triple, 0, cc.step, evidence, params.correlate)]
    if params.fast:
        frames, cam = _triple_camera(triple)
        scene = None if evidence is None else dataclasses.replace(
            evidence, shift=cam[np.searchsorted(frames, evidence.index)], leads=FAST_LEADS)
        parts.append(_band(triple, 1, cc.step, scene, params.fast_correlate, cc.length))
    corr = parts[0] if len(parts) == 1 else Correlation(
        segments=np.concatenate([c.segments for c in parts]),
        index=np.concatenate([c.index for c in parts]),
        positions=np.concatenate([c.positions for c in parts]),
        significance=np.concatenate([c.significance for c in parts]))
    _lap(timings, "correlate", t0)
    return corr


#: the fast band's merit keeps a target near its position in the window's last frame
#: (its wide dilations do not let the path's past outweigh the present): the search of
#: the verification starts 0 and 1 frame of motion ahead of the fused points (0, 0.5, 1,
#: 2 found the same targets on the simulator at twice the cost)
FAST_LEADS = (0.0, 1.0)


def _triple_camera(triple) -> tuple[np.ndarray, np.ndarray]:
    """(frames (F,), offsets (F, 2)): the camera's offsets of the 3 windows' frames."""
    frames = np.concatenate([np.arange(p.start, p.start + len(p.camera)) for p in triple])
    return frames, np.concatenate([p.camera for p in triple])


def _band(triple, band: int, step: int, evidence, kwargs, length: int = 0) -> Correlation:
    """``correlate`` on one band's points of 3 windows. Band 1 is in scene coordinates:
    its points (the merit's, in the image of each window's last frame) lose that frame's
    camera offset, and its verified positions get the offset at their report time."""
    rows = [np.flatnonzero(p.table["band"] == band) for p in triple]
    tables_ = [p.table[r] for p, r in zip(triple, rows)]
    if band == 1:
        for t, p in zip(tables_, triple):
            t["x"] -= p.camera[length - 1, 0]
            t["y"] -= p.camera[length - 1, 1]
    corr = correlate(*tables_, step, evidence, **kwargs)
    index = np.column_stack([r[corr.index[:, i]] for i, r in enumerate(rows)]) \
        if len(corr.index) else corr.index
    positions, segments = corr.positions, corr.segments
    if band == 1 and len(segments):
        frames, cam = _triple_camera(triple)
        positions = positions.copy()
        for i, (p, (fx, fy)) in enumerate(zip(triple, (("x1", "y1"), ("x2", "y2"),
                                                       ("x3", "y3")))):
            at = p.start + (length - 1) / 2.0
            positions[:, i, 0] += np.interp(at, frames, cam[:, 0])
            positions[:, i, 1] += np.interp(at, frames, cam[:, 1])
            segments[fx] += p.camera[length - 1, 0]
            segments[fy] += p.camera[length - 1, 1]
        # image velocity: the scene's plus the camera's mean motion over the windows
        span = max(1, frames[-1] - frames[0])
        segments["vx"] += (cam[-1, 0] - cam[0, 0]) / span
        segments["vy"] += (cam[-1, 1] - cam[0, 1]) / span
    return Correlation(segments=segments, index=index, positions=positions,
                       significance=corr.significance)


class _StageParams:
    """The stages' keyword arguments, built once per run (not per window)."""

    def __init__(self, config: ProcessConfig):
        self.suppress = asdict(config.suppress)
        self.combine = {**asdict(config.combine), "step": config.combine.length}
        self.detect = asdict(config.detect)
        self.fuse = asdict(config.fuse)
        self.correlate = asdict(config.correlate)
        # the fast band: the same stages with a wide merit that follows the camera, a
        # point test on it and chains in scene coordinates (needs the dp projection and
        # the verification, which controls its loose first stage's false alarms)
        fast = config.fast
        self.fast = (fast.radius > 0 and config.combine.projection == "dp"
                     and config.correlate.verify > 0)
        self.fast_combine = {**self.combine, "dp_radius": fast.radius}
        self.fast_detect = {**self.detect, "window": 1, "k": fast.k, "sigma": fast.sigma}
        self.fast_fuse = {**self.fuse, "extent": fast.extent}
        self.fast_correlate = {**self.correlate, "max_speed": float(fast.radius),
                               "max_deviation": fast.max_deviation}
        # the verification of chains needs the matched residual frames of each window
        self.matched = config.correlate.verify > 0
        self.psf = config.combine.dp_smooth


def _front(block, previous, params: _StageParams, timings: dict | None, following=None,
           camera=None):
    """One window's suppression, combination, detection and fusion (``following``: the
    raw frames after the window that the first frames' background looks ahead to;
    ``camera``: the offsets of previous, block and following).

    Returns (candidates, candidate pixels, matched residual frames (L, H, W) or None).
    """
    t = time.perf_counter()
    residual = suppress(block, previous=previous, following=following, camera=camera,
                        **params.suppress)
    t = _lap(timings, "suppress", t)
    presmoothed = params.matched and params.combine["projection"] == "dp" and params.psf > 0
    if presmoothed:
        # the dp merit and the matched filter smooth with the same Gaussian: smooth each
        # residual once, in place, and tell both stages it is done (same values)
        for r in residual:
            cv2.GaussianBlur(r, (0, 0), params.psf, dst=r, borderType=cv2.BORDER_REFLECT)
    done = {"dp_smooth": 0.0} if presmoothed else {}
    comb = combine(residual, **{**params.combine, **done})[0]
    fast = None
    if params.fast:
        n_prev = 0 if previous is None else len(previous)
        window_camera = None if camera is None else camera[n_prev:n_prev + len(residual)]
        fast = combine(residual, window_camera, **{**params.fast_combine, **done})[0]
    matched = None
    if params.matched:
        # the residuals become the matched frames in place (no second window of frames)
        smooth = 0.0 if presmoothed else params.psf
        standardise([matched_frame(r, smooth, out=r) for r in residual])
        matched = residual
    del residual
    t = _lap(timings, "combine", t)
    det = detect(comb, **params.detect)
    det_fast = None if fast is None else detect(fast, **params.fast_detect)
    t = _lap(timings, "detect", t)
    cand = fuse(det, comb, **params.fuse)
    if fast is not None:
        more = fuse(det_fast, fast, **params.fast_fuse)
        more["band"] = 1
        cand = np.concatenate([cand, more])
    _lap(timings, "fuse", t)
    return cand, det.count, matched


def _evidence(pending, cc) -> Evidence | None:
    """The matched frames of the 3 pending windows, each frame once (windows may overlap)."""
    if pending[0].matched is None:
        return None
    blocks, frames, index = [], [], []
    for p in pending:
        # the frames after the last one taken: the window's tail, a block in place
        first = 0 if not index else max(0, index[-1] + 1 - p.start)
        if first < len(p.matched):
            blocks.append(p.matched[first:])
            frames.extend(p.matched[first:])
            index.extend(range(p.start + first, p.start + len(p.matched)))
    # the dp merit's fused point sits near the window's last frame (trailing its target
    # by some frames: DP_LEADS); other projections' at the window's middle
    mid = (cc.length - 1) / 2.0
    dp = cc.projection == "dp"
    at = cc.length - 1 if dp else mid
    return Evidence(frames=blocks, index=np.array(index),
                    times=tuple(p.start + at for p in pending),
                    report=tuple(p.start + mid for p in pending), sigma=noise_level(frames),
                    leads=DP_LEADS if dp else (0.0,))


class _Ready:
    """A result computed on the calling thread, with the interface of a Future."""

    def __init__(self, value):
        self.value = value

    def result(self):
        return self.value


def _lap(timings: dict | None, name: str, t0: float) -> float:
    """Add the seconds since ``t0`` to ``timings[name]``; return the current time."""
    t = time.perf_counter()
    if timings is not None:
        with _TIMINGS_LOCK:
            timings[name] = timings.get(name, 0.0) + (t - t0)
    return t


def detect_sequence(frames, config: ProcessConfig | None = None, *,
                    progress: bool = False, workers: int = 1) -> dict[str, np.ndarray]:
    """Run the front end over an in-memory sequence and collect the tables.

    Parameters
    ----------
    frames : ndarray of shape (T, H, W) or irdetect.io.FrameSource
    config : ProcessConfig, optional
    workers : int
        Threads over windows (``iter_results``); the results do not depend on it.

    Returns
    -------
    dict
        ``candidates``, ``detections``, ``segments``, ``camera`` (``irdetect.tables``
        dtypes; x = column, y = row in px) and ``tracks`` (``initiate_tracks`` on the
        detections).

    Examples
    --------
    >>> from irdetect.simulate import simulate
    >>> frames, truth = simulate("wan2008", snr=4, rng=1)
    >>> out = detect_sequence(frames)
    >>> len(out["detections"]) > 0
    True
    """
    config = config or ProcessConfig()
    parts: dict[str, list] = {"candidates": [], "detections": [], "segments": [],
                              "camera": []}
    for chunk in iter_results(frames, config, progress=progress, workers=workers):
        for name, rows in chunk.items():
            parts[name].append(rows)
    out = {name: (np.concatenate(rows) if rows else tables.empty(name))
           for name, rows in parts.items()}
    out["tracks"] = initiate_tracks(out["detections"], config, out["camera"])
    return out


def check_config(config: ProcessConfig, path=None, frame_shape=(32, 32)) -> None:
    """Check every stage's parameters before a run: the stages' own checks, on blank
    frames (``detect_sequence`` over 3 combined frames of 32 x 32 zeros, a few ms), and
    the track initiation's grid on detections at the corners of a frame of
    ``frame_shape`` (H, W).

    Raises
    ------
    InputError
        A parameter a stage refuses (out of range, unknown choice, a grid too fine for
        the frame), naming ``path`` (the configuration file): otherwise the stage would
        raise mid-run, after minutes.
    """
    from irdetect.initiate import initiate_detections

    for stage in dataclasses.fields(config):
        section = getattr(config, stage.name)
        for field in dataclasses.fields(section) if dataclasses.is_dataclass(section) else ():
            value = getattr(section, field.name)
            if (isinstance(value, int) and not isinstance(value, bool)
                    and abs(value) > MAX_LENGTH and field.name != "n_theta"):
                raise InputError(f"{stage.name}.{field.name} = {value}: integer settings (sizes "
                                 f"in px or frames) lie within +-{MAX_LENGTH}", path)
            if isinstance(value, float) and not (value == 0 or 1 / MAX_SETTING <= abs(value)
                                                 <= MAX_SETTING):
                raise InputError(f"{stage.name}.{field.name} = {value}: real settings are 0 or "
                                 f"finite numbers of magnitude {1 / MAX_SETTING:g} to "
                                 f"{MAX_SETTING:g}", path)
    h, w = frame_shape
    corners = tables.from_columns(
        tables.DETECTION, x=[0.0, w - 1.0, 0.0, w - 1.0], y=[0.0, 0.0, h - 1.0, h - 1.0],
        frame_start=[0, 0, 36, 36], frame_end=[11, 11, 47, 47], combined_frame=[0, 0, 3, 3])
    with refused_settings(path):
        detect_sequence(np.zeros((min_frames(config), 32, 32), np.float32), config)
        initiate_detections(corners, **asdict(config.initiate))


def check_frames(shape, config: ProcessConfig, path=None) -> None:
    """Refuse frames a run cannot use before it starts: frames smaller than ``MIN_SIDE``
    px a side (no room for a target and its background), or a window of frames larger
    than the memory available (estimated as ``WINDOW_BYTES_PER_PIXEL`` bytes per pixel
    of the combined frame's ``length`` frames).

    Parameters
    ----------
    shape : tuple of int
        (T, H, W) of the sequence.
    """
    _, h, w = shape
    if min(h, w) < MIN_SIDE:
        raise InputError(f"frames of {w}x{h} px are too small: a target and its "
                         f"background need at least {MIN_SIDE}x{MIN_SIDE} px", path)
    need = WINDOW_BYTES_PER_PIXEL * config.combine.length * h * w
    available = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    if need > available:
        raise InputError(f"a window of {config.combine.length} frames of {w}x{h} px needs "
                         f"about {need / 2**30:.1f} GiB, {available / 2**30:.1f} GiB free "
                         "(use shorter combined frames or smaller frames)", path)


def initiate_tracks(detections: np.ndarray, config: ProcessConfig,
                    camera=None) -> np.ndarray:
    """Tracks from the confirmed detections (``irdetect.initiate``), TRACK table.

    With the camera's offsets (a CAMERA table) of a moving camera, tracks are initiated
    twice: on the image positions (a target the camera holds, whose scene path is the
    camera's) and on the scene positions, image minus offset (a target straight in the
    scene under a panning or shaking camera; ``scene`` rows, their positions follow the
    camera, ``irdetect.initiate.track_positions``). Of two tracks that claim mostly the
    same detections the one whose positions lie nearer them is kept.
    """
    from irdetect.initiate import camera_at, initiate_detections

    params = asdict(config.initiate)
    image = initiate_detections(detections, **params)
    if camera is None or len(camera) < 2 or len(detections) < 2 or not (
            np.ptp(camera["dx"]) >= MOVING_PX or np.ptp(camera["dy"]) >= MOVING_PX):
        return image
    t = 0.5 * (detections["frame_start"] + detections["frame_end"])
    scene_det = detections.copy()
    off = camera_at(camera, t)
    scene_det["x"] -= off[:, 0]
    scene_det["y"] -= off[:, 1]
    scene = initiate_detections(scene_det, **params)
    if len(scene):
        # into the image coordinates of each track's first frame
        start = camera_at(camera, scene["frame_start"])
        scene["x0"] += start[:, 0]
        scene["y0"] += start[:, 1]
        scene["rho"] += (start[:, 0] * np.cos(scene["theta"])
                         + start[:, 1] * np.sin(scene["theta"]))
        scene["scene"] = True
    both = np.concatenate([image, scene])
    keep = _distinct_tracks(both, detections, camera, float(config.initiate.gate))
    out = both[keep]
    out["track_id"] = np.arange(len(out))
    return out


#: the camera's offsets over the sequence spanning this many px make it "moving" for the
#: track initiation (scene tracks are tried beside the image ones)
MOVING_PX = 1.0


def _distinct_tracks(tracks, detections, camera, gate: float) -> np.ndarray:
    """Indices of tracks to keep: of two whose supporting detections (those of their
    span within ``gate`` px of their positions) overlap by half or more, the one with
    more support, then the smaller mean distance, wins."""
    from irdetect.initiate import track_positions

    if len(tracks) < 2:
        return np.arange(len(tracks))
    t = 0.5 * (detections["frame_start"] + detections["frame_end"])
    pos = track_positions(tracks, t, camera)                              # (n, d, 2)
    dist = np.hypot(pos[..., 0] - detections["x"][None], pos[..., 1] - detections["y"][None])
    inside = (t[None] >= tracks["frame_start"][:, None]) & (t[None] <= tracks["frame_end"][:, None])
    support = inside & (dist <= gate)
    count = support.sum(1)
    mean = np.where(count > 0, (dist * support).sum(1) / np.maximum(count, 1), np.inf)
    order = np.lexsort((mean, -count))
    kept: list[int] = []
    for i in order:                     # a loop over the tracks (a handful)
        if count[i] == 0 and kept:
            continue
        if any((support[i] & support[j]).sum() >= 0.5 * min(count[i], count[j]) > 0
               for j in kept):
            continue
        kept.append(int(i))
    return np.sort(np.array(kept, dtype=np.int64))


def process_file(input, output, config: ProcessConfig | None = None, *, dataset=None,
                 force: bool = False, progress: bool = False, attrs: dict | None = None,
                 workers: int = 1, timings: dict | None = None) -> dict:
    """Run ``irdetect process``: read a sequence, write a results file.

    Parameters
    ----------
    input : str or os.PathLike
        A sequence readable by ``irdetect.io.open_sequence``.
    output : str or os.PathLike
        The results file (``docs/format.md``); written atomically.
    config : ProcessConfig, optional
    dataset : str, optional
        HDF5 dataset path of the frames.
    force : bool
        Overwrite an existing output.
    progress : bool
        tqdm bar over frames.
    attrs : dict, optional
        Extra root attributes for the results file (``irdetect.batch`` stores the input's
        fingerprint here so a re-run can skip finished inputs).
    workers : int
        Threads over windows (``iter_results``); the results do not depend on it.
    timings : dict, optional
        Seconds per stage are added to it (``iter_results``, plus ``write`` for the
        results file and ``initiate`` for track initiation).

    Returns
    -------
    dict
        ``frames``, ``combined_frames``, ``candidates``, ``detections``, ``segments``,
        ``tracks`` (counts) and ``seconds`` (wall time).

    Raises
    ------
    InputError
        Unreadable input, too few frames (the message says how many are needed), an
        existing output without ``force``.
    """
    from irdetect.io import ResultsWriter, check_output_path, open_sequence

    config = config or ProcessConfig()
    t0 = time.perf_counter()
    check_output_path(output, force, inputs=(input,))
    counts = {"candidates": 0, "detections": 0, "segments": 0}
    with open_sequence(input, dataset) as src:
        n_frames, height, width = src.shape
        try:
            run = fit_config(config, n_frames)
        except ValueError as exc:
            raise InputError(str(exc), input) from None
        check_frames(src.shape, run, input)
        check_config(run, frame_shape=(height, width))
        attrs = {"config": to_json(run), "input": os.fspath(Path(input).name),
                 "input_path": os.fspath(Path(input).resolve()),
                 "combined_length": run.combine.length,
                 "combined_step": run.combine.step,
                 "n_frames": n_frames, "frame_height": height, "frame_width": width,
                 **(attrs or {})}
        if run is not config:
            # a short sequence: say what ran instead of the configured combined frames
            attrs["short_sequence"] = True
            attrs["configured_length"] = config.combine.length
            log.info("%d frames: combined frames of %d frames instead of %d (a short sequence)",
                     n_frames, run.combine.length, config.combine.length)
        detections, camera = [], []
        with ResultsWriter(output, force=force, attrs=attrs, inputs=(input,)) as out:
            n_combined = 0
            for chunk in iter_results(src, config, progress=progress, workers=workers,
                                      timings=timings):
                t = time.perf_counter()
                n_combined += 1
                for name, rows in chunk.items():
                    out.append(name, rows)
                    if name in counts:
                        counts[name] += len(rows)
                detections.append(chunk["detections"])
                camera.append(chunk["camera"])
                _lap(timings, "write", t)
            t = time.perf_counter()
            dets = np.concatenate(detections) if detections else tables.empty(tables.DETECTION)
            tracks = initiate_tracks(dets, config, np.concatenate(camera) if camera
                                     else tables.empty(tables.CAMERA))
            t = _lap(timings, "initiate", t)
            out.write("tracks", tracks)
            out.attrs["n_combined"] = n_combined
        _lap(timings, "write", t)
    seconds = time.perf_counter() - t0
    log.info("%d frames -> %d combined frames, %d candidates, %d detections, %d segments, "
             "%d tracks", n_frames, n_combined, counts["candidates"], counts["detections"],
             counts["segments"], len(tracks))
    return {"frames": int(n_frames), "combined_frames": n_combined, **counts,
            "tracks": int(len(tracks)), "seconds": seconds}


# --- helpers --------------------------------------------------------------------------

class _Pending:
    """Candidates of one combined frame waiting for the segments that may confirm them."""

    def __init__(self, table: np.ndarray, dp_length: int = 0, matched=None, start: int = 0,
                 tolerance: float = 5.0, camera=None):
        self.table = table
        # the camera's offsets (L, 2) of the window's frames
        self.camera = np.zeros((max(1, dp_length), 2)) if camera is None else camera
        self.tolerance = tolerance  # verified positions this close are one target
        self.dp_length = dp_length
        self.matched = matched      # matched residual frames of the window (or None)
        self.start = start          # the window's first frame
        n = len(table)
        self.vx = np.full(n, np.nan)
        self.vy = np.full(n, np.nan)
        self.pos = np.full((n, 2), np.nan)
        self.seg_score = np.full(n, -np.inf)

    def confirm(self, rows: np.ndarray, segments: np.ndarray, positions=None) -> None:
        """Mark ``rows`` confirmed; keep the velocity (and verified position at the
        window's middle, when given) of the best-scoring segment."""
        if len(rows) == 0:
            return
        self.table["confirmed"][rows] = True
        # several segments may share a point: take them in increasing score so the
        # best one is written last (a loop over a handful of segments)
        for s in np.argsort(segments["score"], kind="stable"):
            r = rows[s]
            if segments["score"][s] >= self.seg_score[r]:
                self.seg_score[r] = segments["score"][s]
                self.vx[r], self.vy[r] = segments["vx"][s], segments["vy"][s]
                if positions is not None:
                    self.pos[r] = positions[s]

    def emit(self, segments: np.ndarray) -> dict:
        c = self.table
        self._merge_duplicates()
        keep = c["confirmed"]
        det = np.zeros(int(keep.sum()), dtype=tables.DETECTION)
        for name in ("x", "y", "frame_start", "frame_end", "combined_frame", "intensity",
                     "score", "n_members"):
            det[name] = c[name][keep]
        det["vx"], det["vy"] = self.vx[keep], self.vy[keep]
        if self.dp_length:
            # the dp merit puts a target at its position in the window's last frame;
            # report it at the window's middle time like the other projections
            back = (self.dp_length - 1) / 2.0
            det["x"] -= det["vx"] * back
            det["y"] -= det["vy"] * back
        # a verified segment gives the target's position at the window's middle directly
        pos = self.pos[keep]
        ok = np.isfinite(pos[:, 0])
        det["x"][ok], det["y"][ok] = pos[ok, 0], pos[ok, 1]
        self.matched = None         # release the frames
        return {"candidates": c, "detections": det, "segments": segments}


    def _merge_duplicates(self) -> None:
        """One target split into two fused points, each confirmed by a different segment
        (windows k-2..k and k-1..k+1), is one detection: of two confirmed points whose
        verified positions lie within ``tolerance`` px, the lower-scoring is unconfirmed."""
        rows = np.flatnonzero(self.table["confirmed"] & np.isfinite(self.pos[:, 0]))
        if len(rows) < 2:
            return
        pairs = cKDTree(self.pos[rows]).query_pairs(self.tolerance, output_type="ndarray")
        for a, b in pairs:          # a loop over duplicate pairs (rare)
            ra, rb = rows[a], rows[b]
            if not (self.table["confirmed"][ra] and self.table["confirmed"][rb]):
                continue
            lose = rb if self.seg_score[ra] >= self.seg_score[rb] else ra
            self.table["confirmed"][lose] = False


class _Reader:
    """Read windows [a, b) with the ``history`` raw frames before a, in the stored dtype.

    Frames go into one reused buffer of ``history + length + block`` frames, read ahead
    in blocks the storage favours (an HDF5 chunk: a compressed chunk read in pieces is
    decompressed once per piece), so memory is bounded whatever the sequence length.
    The arrays returned are views of the buffer, valid until the next ``read``.
    """

    #: largest read-ahead in bytes (a 64-frame chunk of 640x512 uint16 frames is 42 MB)
    MAX_BLOCK_BYTES = 48 << 20

    def __init__(self, frames, history: int, length: int, ahead: int = 0,
                 camera: bool = True):
        self.frames = frames
        self.history = history
        n, h, w = (int(v) for v in frames.shape)
        self.n = n
        # the camera's offsets of every frame read, measured once, in order (zeros when
        # the configuration takes the camera to be still)
        self.motion = CameraMotion((h, w)) if camera else None
        self.offsets = np.zeros((n, 2))
        self.measured = 0           # frames [0, measured) have offsets
        frame_bytes = h * w * np.dtype(frames.dtype).itemsize
        chunk = max(1, int(getattr(frames, "block_frames", 1)))
        self.block = max(length, min(chunk, max(1, self.MAX_BLOCK_BYTES // frame_bytes)))
        # the first window may also read ``ahead`` frames after it (it has no history)
        size = max(history + length + self.block, length + ahead)
        self.buf = np.empty((min(n, size), h, w), frames.dtype)
        self.lo = self.hi = 0     # the buffer holds raw frames [lo, hi)

    def read(self, a: int, b: int):
        lo = max(0, a - self.history)
        if not self.lo <= lo <= self.hi:
            self.lo = self.hi = lo
        if b > self.hi:
            keep = self.hi - lo
            if lo > self.lo:            # drop frames before lo: move the rest to the front
                self.buf[:keep] = self.buf[lo - self.lo:self.hi - self.lo]
            self.lo = lo
            stop = min(self.n, max(b, self.hi + self.block), lo + len(self.buf))
            self._fill(self.hi, stop, self.buf[keep:keep + stop - self.hi])
            self.hi = stop
        data = self.buf[lo - self.lo:b - self.lo]
        return data[a - lo:], data[:a - lo]

    def _fill(self, start: int, stop: int, out: np.ndarray) -> None:
        if hasattr(self.frames, "read_into"):
            self.frames.read_into(start, stop, out)
        else:
            out[...] = self.frames[start:stop]
        # a file's frames must be finite (docs/format.md; arrays given to detect_sequence
        # may hold NaN, which finds nothing there); NaN or inf anywhere makes the sum
        # non-finite: one pass, no mask allocated
        if (out.dtype.kind == "f" and isinstance(self.frames, FrameSource)
                and not np.isfinite(np.sum(out, dtype=np.float64))):
            raise InputError(f"frames {start}..{stop - 1} hold NaN or inf values",
                             getattr(self.frames, "path", None))
        if self.motion is not None and stop > self.measured:
            # frames skipped (windows with gaps) keep the last offset
            first = max(start, self.measured)
            self.offsets[self.measured:first] = self.offsets[self.measured - 1] \
                if self.measured else 0.0
            self.offsets[first:stop] = self.motion.update(out[first - start:])
            self.measured = stop


def _bar(total: int, progress: bool):
    if not progress:
        return None
    from tqdm import tqdm
    return tqdm(total=total, unit="frame", desc="irdetect", leave=False)
