"""Streaming: memory does not grow with sequence length; the fast paths change no result.

Not timed (the throughput numbers are in scripts/bench_throughput.py). Each test draws
the scene it then processes.
"""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from irdetect import tables
from irdetect.config import ProcessConfig, SuppressConfig
from irdetect.io import ResultsWriter, open_sequence, read_results, write_sequence
from irdetect.pipeline import _Reader, iter_results
from irdetect.simulate import simulate
from irdetect.simulate.sequence import load_scenario, simulate_blocks

SIZE = 64


def _write_long(path, n_frames: int, seed: int = 0) -> int:
    """Stream a uint16 sequence of slow targets to ``path``; returns its size in bytes."""
    s = load_scenario("wan2008", height=SIZE, width=SIZE, n_frames=n_frames, dtype="uint16",
                      background=1000.0, noise_sigma=20.0, snr=5.0, n_targets=3,
                      speed=[0.08, 0.12], directions=[])
    blocks, _ = simulate_blocks(s, rng=seed, block=64)
    write_sequence(path, blocks, chunk_frames=32)
    return n_frames * SIZE * SIZE * 2


def _peak_bytes(path, out, config=None) -> tuple[int, dict]:
    """Peak traced memory of the streaming part of ``irdetect process``: frames read in
    windows, every stage, tables written as they complete (what ``process_file`` does
    before track initiation, which runs once over all the detections at the end: its
    own test is below)."""
    counts = {"frames": 0, "combined_frames": 0, "detections": 0}
    tracemalloc.start()
    try:
        with open_sequence(path) as src, ResultsWriter(out, force=True) as res:
            counts["frames"] = len(src)
            for chunk in iter_results(src, config):
                counts["combined_frames"] += 1
                counts["detections"] += len(chunk["combined_detections"])
                for name, rows in chunk.items():
                    res.append(name, rows)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return peak, counts


# one suppressor per run: ``auto`` switches per window, so a short and a long run could
# differ in which (temporal: 12 past frames; registered: 19 and a fixed-pattern stack)
@pytest.mark.parametrize("method", ["temporal", "registered"])
def test_peak_memory_does_not_grow_with_sequence_length(tmp_path, method, monkeypatch):
    config = ProcessConfig(suppress=SuppressConfig(method=method))
    # the writer's buffer of result rows (up to FLUSH_ROWS per table, one small array per
    # window and table: ~100 KB over the long run) is not the stages' memory
    monkeypatch.setattr(ResultsWriter, "FLUSH_ROWS", 16)
    n = 60
    short, long_ = tmp_path / "short.h5", tmp_path / "long.h5"
    short_bytes = _write_long(short, n)
    long_bytes = _write_long(long_, 10 * n)
    _peak_bytes(short, tmp_path / "warm.h5", config)   # first-call caches (kernels, imports)
    peak_short, s_short = _peak_bytes(short, tmp_path / "short.irdetect.h5", config)
    peak_long, s_long = _peak_bytes(long_, tmp_path / "long.irdetect.h5", config)
    assert s_long["frames"] == 10 * s_short["frames"]
    assert s_long["combined_frames"] >= 9 * s_short["combined_frames"]
    assert s_long["detections"] > 0
    # 10x the frames: the peak stays within a quarter of the short run's ...
    assert peak_long < 1.25 * peak_short, (peak_short, peak_long)
    # ... and grows by under 5 % of the extra frames' bytes (holding them would be 100 %)
    assert peak_long - peak_short < 0.05 * (long_bytes - short_bytes), (peak_short, peak_long)


@pytest.mark.parametrize("history,length,step,chunk", [(12, 12, 12, 32), (19, 12, 12, 5),
                                                         (0, 12, 6, 7), (4, 5, 9, 64)])
def test_reader_windows_match_direct_slices(tmp_path, history, length, step, chunk):
    rng = np.random.default_rng(3)
    frames = rng.integers(0, 4000, size=(101, 9, 11)).astype(np.uint16)
    path = tmp_path / "seq.h5"
    write_sequence(path, frames, chunk_frames=chunk)
    with open_sequence(path) as src:
        for source in (src, frames):
            reader = _Reader(source, history, length)
            for a in range(0, len(frames) - length + 1, step):
                block, previous = reader.read(a, a + length)
                lo = max(0, a - history)
                np.testing.assert_array_equal(block, frames[a:a + length])
                np.testing.assert_array_equal(previous, frames[lo:a])
                assert block.dtype == np.uint16
                # one bounded buffer: history + length + one read-ahead block
                assert len(reader.buf) <= history + length + max(length, chunk)


@pytest.mark.parametrize("scene,workers", [("clutter", 2), ("wan2008", 3)])
def test_threads_over_windows_give_the_same_tables(scene, workers):
    # threads run the front end of several windows and the correlation of window triples
    # at once; the results are taken up in order, so every table is byte for byte the same
    frames, _ = simulate(scene, rng=4, n_frames=84, **({"snr": 2.0} if scene == "wan2008"
                                                       else {}))
    serial = list(iter_results(frames))
    threaded = list(iter_results(frames, workers=workers))
    assert len(serial) == len(threaded) == 84 // 12
    for a, b in zip(serial, threaded):
        for name in ("candidates", "combined_detections", "segments", "frame_detections"):
            assert a[name].tobytes() == b[name].tobytes()
    assert sum(len(a["combined_detections"]) for a in serial) > 0
    assert sum(len(a["segments"]) for a in serial) > 0


def test_timings_name_every_stage(tmp_path):
    frames, _ = simulate("wan2008", rng=2, n_frames=48)
    timings = {}
    list(iter_results(frames, timings=timings))
    assert set(timings) == {"read", "suppress", "combine", "frame", "detect", "fuse",
                            "correlate", "operate"}
    assert all(v >= 0 for v in timings.values())
    with pytest.raises(ValueError, match="workers"):
        list(iter_results(frames, workers=0))


def test_buffered_appends_write_every_row_in_order(tmp_path):
    rng = np.random.default_rng(5)
    parts = []
    with ResultsWriter(tmp_path / "r.h5") as out:
        out.append("candidates", tables.empty(tables.CANDIDATE))
        for size in (0, 3000, 1, 2000, 0, 5000, 7):      # crosses FLUSH_ROWS several times
            rows = np.zeros(size, tables.CANDIDATE)
            rows["x"] = rng.normal(size=size)
            out.append("candidates", rows)
            parts.append(rows.copy())
            rows["x"] = 0.0          # the writer must have kept its own copy
        out.append("segments", tables.empty(tables.SEGMENT))
    res = read_results(tmp_path / "r.h5")
    want = np.concatenate(parts)
    assert len(want) == 10008
    assert res["candidates"].tobytes() == want.tobytes()
    assert len(res["segments"]) == 0 and res["segments"].dtype == tables.SEGMENT


def _lines_of_detections(n_windows: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(DETECTION rows, CAMERA rows) of a long run's end: two new targets every 10 windows
    of 12 frames, each on a straight line at 1 px/frame for 10 windows, one detection per
    window at its middle frame, under a camera drifting 0.05 px/frame (so the initiation
    tries scene tracks too). x = column, y = row."""
    rng = np.random.default_rng(seed)
    rows = []
    for first in range(0, n_windows, 10):
        for _ in range(2):
            x0, y0 = rng.uniform(20, 180, 2)
            vx, vy = rng.uniform(-1, 1, 2)
            for k in range(first, min(first + 10, n_windows)):
                t = 12 * k + 5.5 - 12 * first
                rows.append((x0 + vx * t + 0.05 * 12 * k, y0 + vy * t, 12 * k, 12 * k + 11, k,
                             vx, vy))
    x, y, fs, fe, k, vx, vy = map(np.array, zip(*rows))
    det = tables.from_columns(tables.DETECTION, x=x, y=y, frame_start=fs, frame_end=fe,
                              combined_frame=k, vx=vx, vy=vy, score=np.ones(len(x)),
                              n_members=np.ones(len(x), int),
                              path=np.full(len(x), tables.PATH_COMBINED, np.int8))
    f = np.arange(12 * n_windows)
    cam = tables.from_columns(tables.CAMERA, frame=f, dx=0.05 * f, dy=np.zeros(len(f)))
    return det[np.argsort(det["combined_frame"], kind="stable")], cam


def _initiation_peak(n_windows: int) -> tuple[int, int]:
    """(peak traced bytes, tracks) of the track initiation that ends a run of
    ``n_windows`` windows (``irdetect.pipeline.fusion``)."""
    from irdetect.combine import window_starts
    from irdetect.pipeline.fusion import initiate_tracks, track_paths

    det, cam = _lines_of_detections(n_windows)
    config = ProcessConfig()
    tracemalloc.start()
    try:
        tracks = initiate_tracks(det, config, cam, shape=(200, 200),
                                 starts=window_starts(12 * n_windows, length=12, step=12),
                                 length=12)
        track_paths(tracks, det, cam, config.initiate.gate * config.initiate.sigma)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return peak, len(tracks)


def test_track_initiation_at_the_end_grows_with_the_detections_not_their_square():
    # 10x the windows: 10x the detections and 10x the tracks. Anything of shape (tracks,
    # detections) would grow 100x (it did: 0.6 -> 31 MB); the initiation's own work about
    # 10x at most (0.6 -> 1.8 MB).
    peak_short, n_short = _initiation_peak(100)
    peak_long, n_long = _initiation_peak(1000)
    assert n_short >= 15 and n_long >= 9 * n_short, (n_short, n_long)
    assert peak_long < 10 * peak_short, (peak_short, peak_long)
