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
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict
from pathlib import Path
from typing import Iterator

import numpy as np

from irdetect import kernels, tables
from irdetect.binning import (MAX_BIN, Binned, binned_mask, check_bin, sequence_floor,
                              to_input)
from irdetect.combine import frames_needed, window_starts
from irdetect.config import ProcessConfig, to_json
from irdetect.errors import InputError, refused_settings
from irdetect.exclude import exclusion_mask, read_exclusions
from irdetect.pipeline import combined
from irdetect.pipeline.combined import Pending, StageParams, correlate_windows, front
from irdetect.pipeline.fusion import SUPPORT_GATE, finish, initiate_tracks
from irdetect.pipeline.reader import Reader
from irdetect.pipeline.timing import Ready, lap
from irdetect.suppress import STILL_PX, future_frames, past_frames

__all__ = ["CHUNK_TABLES", "N_CORRELATE", "check_config", "check_frames", "check_size",
           "detect_sequence", "finish", "fit_config", "initiate_tracks", "iter_results",
           "min_frames", "process_file"]

#: the names tests and scripts used before ``irdetect.pipeline`` became a package
_Reader = Reader

#: the tables ``iter_results`` yields per window (``finish`` makes the run's final
#: /detections, /frame_tracks and /tracks from them)
CHUNK_TABLES = ("candidates", "combined_detections", "segments", "camera", "frame_detections")

log = logging.getLogger(__name__)

#: combined frames the correlation needs
N_CORRELATE = 3


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
    raise ValueError(f"the sequence has {n_frames} frame{'' if n_frames == 1 else 's'}; "
                     f"detection needs at least {need} "
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
        ``combine``, ``frame``, ``detect``, ``fuse``, ``correlate`` (summed over threads)
        and ``operate`` (a window's operating point, its detections' SNR and support
        along their tracks: ``pipeline.combined.Pending.emit``).

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
    # the compiled kernels the stages use: the verification's and the per-frame path's
    used = (["sampling"] if config.correlate.verify > 0 else []) + \
        (["peaks"] if config.frame.enabled else [])
    if used:
        kernels.warm_up(*used)
    n_frames = shape[0]
    config = fit_config(config, n_frames)
    cc = config.combine
    rate = config.operating.false_rate
    if not (np.isfinite(rate) and rate >= 0):
        raise ValueError(f"operating.false_rate must be a number >= 0, got {rate!r}")
    if int(workers) != workers or workers < 1:
        raise ValueError(f"workers must be an integer >= 1, got {workers!r}")
    # every ``step`` frames, and the tail window over the last frames those leave
    # (``CombineConfig.tail``; its triple's spacing is uneven, ``correlate_windows``)
    starts = window_starts(n_frames, length=cc.length, step=cc.step, tail=cc.tail)
    regular = len(window_starts(n_frames, length=cc.length, step=cc.step))
    params = StageParams(config)
    params.exclude = binned_mask(exclusion_mask(config.exclude, shape[1:]), params.bin)
    if params.bin > 1:
        frames = Binned(frames, params.bin)
    # integer frames' quantisation (the input's, a binned block's mean holds less)
    params.floor = sequence_floor(frames, params.psf) if n_frames else 0.0
    # the first window(s) look ahead: their first frames have no past (``lead_in``)
    ahead = [future_frames(start=int(s), stop=int(s) + cc.length, **params.suppress)
             for s in starts]
    reader = Reader(frames, past_frames(**params.suppress), cc.length, max(ahead),
                     camera=config.suppress.method in ("auto", "registered"),
                     gain_step=params.gain_step)
    pool = ThreadPoolExecutor(int(workers)) if workers > 1 else None
    fronts: deque = deque()      # windows read and submitted, in order
    pending: deque = deque()
    segment_id = 0
    bar = _bar(n_frames, progress)
    # the first frame of each of the last windows: the long-memory background
    firsts: deque = deque(maxlen=params.long_memory or 1)
    long_memory = params.long_memory and config.suppress.method in ("auto", "temporal")

    def long_past(s: int, end: int):
        """The earlier windows' first frames, while the camera held still since the
        oldest of them (else None)."""
        if not (long_memory and firsts):
            return None
        span = reader.offsets[firsts[0][0]:end]
        if np.ptp(span, axis=0).max() >= STILL_PX:
            return None
        return np.stack([f for _, f in firsts])

    def submit(k: int):
        t0 = time.perf_counter()
        s = int(starts[k])
        block, previous = reader.read(s, s + cc.length + ahead[k])
        camera = reader.offsets[s - len(previous):s + len(block)]
        block, following = block[:cc.length], block[cc.length:]
        previous = previous if len(previous) else None
        following = following if len(following) else None
        memory = long_past(s, s + cc.length)
        if long_memory:
            firsts.append((s, block[0].copy()))
        if pool is None:
            lap(timings, "read", t0)
            return Ready(front(block, previous, params, timings, following, camera, memory))
        # the reader's buffer is reused: the thread gets its own copy
        block, camera = block.copy(), camera.copy()
        previous = None if previous is None else previous.copy()
        following = None if following is None else following.copy()
        lap(timings, "read", t0)
        return pool.submit(front, block, previous, params, timings, following, camera, memory)

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
        # the tail window's triple confirms the tail alone: the windows before it keep
        # what their own triples confirmed (their tables are those of ``tail = false``)
        roles = range(N_CORRELATE) if first + N_CORRELATE <= regular else [N_CORRELATE - 1]
        for i in roles:
            pending[i].confirm(corr.index[:, i], segments, corr.positions[:, i])
        first += 1
        done = pending.popleft()
        return with_camera(emit(done, segments), done.start + cc.length, done.peaks)

    # the operating point's windows (``combined.OPERATING_WINDOWS``, read per run)
    beside = combined.OPERATING_WINDOWS
    emitted: deque = deque(maxlen=beside)  # the last windows whose frames stay

    def emit(done: Pending, segments) -> dict:
        """``done.emit`` with the windows beside it; the last windows of the sequence keep
        their frames for the ones after them, which have fewer windows ahead (and the
        tail window overlaps the one before it, which it then skips)."""
        t0 = time.perf_counter()
        k = int(np.searchsorted(starts, done.start))     # done's window index
        chunk = done.emit(segments, pending, reversed(emitted),
                          keep_frames=k >= len(starts) - beside - 1)
        emitted.append(done)
        lap(timings, "operate", t0)
        return chunk

    camera_done = 0              # frames whose /camera rows were emitted

    def with_camera(chunk: dict, end: int, peaks=None) -> dict:
        """The chunk of one window with the /camera rows and the per-frame peaks of its
        frames up to ``end`` not given before (windows may overlap)."""
        nonlocal camera_done
        f = np.arange(camera_done, max(end, camera_done))
        chunk["camera"] = tables.from_columns(tables.CAMERA, frame=f, dx=reader.offsets[f, 0],
                                              dy=reader.offsets[f, 1], gain=reader.gains[f, 0],
                                              level=reader.gains[f, 1],
                                              repeated=np.isin(f, reader.repeats))
        chunk["frame_detections"] = (tables.empty(tables.FRAME_DETECTION) if peaks is None
                                     else peaks[peaks["frame"] >= camera_done])
        camera_done = end
        return chunk

    def unbinned(chunk: dict) -> dict:
        """The chunk in the input's pixels (``irdetect.binning``)."""
        return {name: to_input(name, rows, params.bin) for name, rows in chunk.items()}

    try:
        submitted = 0
        for k, s in enumerate(starts):
            while submitted < len(starts) and len(fronts) < (1 if pool is None else workers):
                fronts.append(submit(submitted))
                submitted += 1
            cand, n_pixels, matched, peaks = fronts.popleft().result()
            cand["frame_start"], cand["frame_end"] = s, s + cc.length - 1
            cand["combined_frame"] = k
            if peaks is not None:
                peaks["frame"] += s
            pending.append(Pending(cand, cc.length if cc.projection == "dp" else 0,
                                    matched, int(s), config.correlate.tolerance,
                                    reader.offsets[s:s + cc.length].copy(), peaks,
                                    SUPPORT_GATE * config.frame.sigma,
                                    config.operating.false_rate, params.exclude))
            log.debug("combined frame %d (frames %d-%d): %d candidate pixels, %d fused points",
                      k, s, s + cc.length - 1, n_pixels, len(cand))
            if k >= N_CORRELATE - 1:
                # windows k-2, k-1, k: with a pool their correlation runs beside the next
                # windows' front end; the results are taken up in order
                triple = list(pending)[-N_CORRELATE:]
                if pool is None:
                    corrs.append(Ready(correlate_windows(triple, cc, params, timings)))
                else:
                    corrs.append(pool.submit(correlate_windows, triple, cc, params, timings))
            while len(corrs) > (0 if pool is None else workers):
                yield unbinned(take())
            if bar is not None:
                bar.update(int(min(starts[k + 1] if k + 1 < len(starts) else n_frames,
                                   n_frames) - bar.n))
        while corrs:
            yield unbinned(take())
        while pending:
            done = pending.popleft()
            yield unbinned(with_camera(emit(done, tables.empty(tables.SEGMENT)),
                                       done.start + cc.length, done.peaks))
        if steps := reader.gain_steps():
            log.info(steps)
        if repeats := reader.repeated():
            log.warning(repeats)
    finally:
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)
        if bar is not None:
            bar.close()


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
    parts: dict[str, list] = {name: [] for name in CHUNK_TABLES}
    for chunk in iter_results(frames, config, progress=progress, workers=workers):
        for name, rows in chunk.items():
            parts[name].append(rows)
    out = {name: (np.concatenate(rows) if rows else tables.empty(tables.BY_NAME[name]))
           for name, rows in parts.items()}
    run = fit_config(config, len(frames))
    out.update(finish(out["combined_detections"], out["frame_detections"], out["camera"],
                      run, n_frames=len(frames), shape=tuple(frames.shape[1:])))
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
    read_exclusions(config.exclude)         # the frames' size: as the run starts
    with refused_settings(path):
        # 32 x 32 px once binned (a bin out of range is refused by the run)
        side = 32 * min(max(1, int(config.suppress.bin)), MAX_BIN)
        detect_sequence(np.zeros((min_frames(config), side, side), np.float32),
                        dataclasses.replace(config, exclude=()))
        initiate_detections(corners, **asdict(config.initiate))


def check_size(shape, path=None, factor: int = 1) -> None:
    """Refuse frames smaller than ``MIN_SIDE`` px a side, (T, H, W) ``shape``, once binned
    by ``factor`` (``suppress.bin``): no room for a target and its background (``process``
    and ``track``)."""
    _, h, w = shape
    if min(h, w) // factor < MIN_SIDE:
        binned = f" binned {factor}x{factor} (suppress.bin)" if factor > 1 else ""
        raise InputError(f"frames of {w}x{h} px{binned} are too small: a target and its "
                         f"background need at least {MIN_SIDE}x{MIN_SIDE} px", path)


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
    b = check_bin(config.suppress.bin)
    check_size(shape, path, b)
    _, h, w = shape
    need = WINDOW_BYTES_PER_PIXEL * config.combine.length * (h // b) * (w // b)
    available = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    if need > available:
        raise InputError(f"a window of {config.combine.length} frames of {w}x{h} px needs "
                         f"about {need / 2**30:.1f} GiB, {available / 2**30:.1f} GiB free "
                         "(use shorter combined frames or smaller frames)", path)


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
        # the tables the fusion needs at the end (small: points, not frames)
        held = {name: [] for name in ("combined_detections", "frame_detections", "camera")}
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
                    if name in held:
                        held[name].append(rows)
                lap(timings, "write", t)
            t = time.perf_counter()
            held = {name: np.concatenate(rows) if rows else tables.empty(tables.BY_NAME[name])
                    for name, rows in held.items()}
            final = finish(held["combined_detections"], held["frame_detections"],
                           held["camera"], run, n_frames=n_frames, shape=(height, width))
            t = lap(timings, "initiate", t)
            for name, rows in final.items():
                out.write(name, rows)
            tracks = final["tracks"]
            counts["detections"] = len(final["detections"])
            out.attrs["n_combined"] = n_combined
        lap(timings, "write", t)
    seconds = time.perf_counter() - t0
    examined = frames_needed(n_combined, length=run.combine.length, step=run.combine.step)
    if examined < n_frames and not run.combine.tail:
        log.info("frames %d-%d come after the last full combined frame and were not "
                 "examined", examined, n_frames - 1)
    log.info("%d frames -> %d combined frames, %d candidates, %d detections, %d segments, "
             "%d tracks", n_frames, n_combined, counts["candidates"], counts["detections"],
             counts["segments"], len(tracks))
    return {"frames": int(n_frames), "combined_frames": n_combined, **counts,
            "tracks": int(len(tracks)), "seconds": seconds}


# --- helpers --------------------------------------------------------------------------

def _bar(total: int, progress: bool):
    if not progress:
        return None
    from tqdm import tqdm
    return tqdm(total=total, unit="frame", desc="irdetect", leave=False)
