"""The whole front end: simulate, run, compare with truth; streaming; bad input."""

import dataclasses
import logging

import h5py
import numpy as np
import pytest

from irdetect import tables
from irdetect.config import ProcessConfig
from irdetect.errors import InputError
from irdetect.io import read_results, write_sequence
from irdetect.metrics.detection import score_detections
from irdetect.pipeline import (detect_sequence, fit_config, iter_results, min_frames,
                               process_file)
from irdetect.simulate import simulate


def _score(out, frames, truth, config=ProcessConfig()):
    return score_detections(out["detections"], truth, n_frames=len(frames),
                            length=config.combine.length, step=config.combine.step,
                            shape=frames.shape[1:])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_wan2008_at_snr4_every_target_and_no_false_detection(seed):
    frames, truth = simulate("wan2008", snr=4, rng=seed)
    out = detect_sequence(frames)
    m = _score(out, frames, truth)
    assert m["targets"] == 20                  # 5 targets x 4 combined frames
    assert m["detected"] == m["targets"] and m["false"] == 0
    # the velocities of the confirmed detections are the simulated 1 px/frame
    speed = np.hypot(out["detections"]["vx"], out["detections"]["vy"])
    assert np.allclose(speed, 1.0, atol=0.2)
    assert out["candidates"]["confirmed"].sum() == len(out["detections"])
    assert len(out["segments"]) >= 10


def test_streaming_file_matches_in_memory_and_writes_the_contract(tmp_path):
    frames, truth = simulate("wan2008", snr=4, rng=5, n_frames=60, height=96, width=128,
                             n_targets=2, directions=(30.0, 200.0))
    seq = tmp_path / "seq.h5"
    write_sequence(seq, frames, truth=truth)
    res = tmp_path / "out.h5"
    summary = process_file(seq, res, ProcessConfig())
    assert set(summary) >= {"frames", "detections", "tracks", "seconds"}
    assert summary["frames"] == 60 and summary["combined_frames"] == 5
    back = read_results(res)
    mem = detect_sequence(frames)
    for name in ("detections", "candidates", "segments"):
        np.testing.assert_array_equal(back[name], mem[name])
    assert back["tracks"].dtype == tables.TRACK
    assert {"irdetect_version", "config", "input", "combined_length"} <= set(back.attrs)
    assert back.attrs["combined_length"] == 12 and back.attrs["input"] == "seq.h5"
    assert summary["detections"] == len(back["detections"]) > 0
    with pytest.raises(InputError, match="exists"):
        process_file(seq, res, ProcessConfig())


def test_the_tail_window_examines_the_frames_after_the_last_full_window(tmp_path, caplog):
    frames, truth = simulate("wan2008", snr=4, rng=5, n_frames=41, height=64, width=64,
                             n_targets=1)
    seq = tmp_path / "seq.h5"
    write_sequence(seq, frames, truth=truth)
    with caplog.at_level(logging.INFO, logger="irdetect"):
        summary = process_file(seq, tmp_path / "out.h5", ProcessConfig())
    assert summary["combined_frames"] == 4              # frames 0-35 and 29-40
    assert not [r for r in caplog.records if "not examined" in r.getMessage()]
    res = read_results(tmp_path / "out.h5")
    assert len(res["camera"]) == 41 and res["frame_detections"]["frame"].max() == 40
    tail = res["detections"][res["detections"]["combined_frame"] == 3]
    assert set(tail["frame_start"]) == {29} and set(tail["frame_end"]) == {40}
    # the target at the tail window's middle frame (34.5), found there
    mid = truth[np.isin(truth["frame"], (34, 35))]
    assert np.hypot(tail["x"] - mid["x"].mean(), tail["y"] - mid["y"].mean()).min() < 1.5
    assert res["tracks"]["frame_end"].max() == 40
    m = score_detections(res["detections"], truth, n_frames=41, length=12, step=12,
                         shape=(64, 64), tail=True)
    assert m["windows"] == 4 and m["detected"] == 4

    # the paper's windows alone: the last frames unexamined, and the log says so
    paper = dataclasses.replace(ProcessConfig().combine, tail=False)
    with caplog.at_level(logging.INFO, logger="irdetect"):
        summary = process_file(seq, tmp_path / "paper.h5",
                               dataclasses.replace(ProcessConfig(), combine=paper))
    assert summary["combined_frames"] == 3              # frames 0-35
    said = [r.getMessage() for r in caplog.records if "not examined" in r.getMessage()]
    assert said == ["frames 36-40 come after the last full combined frame and were not "
                    "examined"]
    paper = read_results(tmp_path / "paper.h5")
    assert len(paper["camera"]) == 36
    # the tail window's triple confirms the tail alone: the other windows' tables are
    # the paper's windows' own, and its segments come on top
    for name in ("detections", "candidates", "frame_tracks"):
        np.testing.assert_array_equal(res[name][res[name]["combined_frame"] < 3], paper[name])
    n = len(paper["segments"])
    np.testing.assert_array_equal(res["segments"][:n], paper["segments"])
    assert len(res["segments"]) > n


def test_overlapping_windows_with_a_spatial_suppressor():
    cfg = ProcessConfig()
    cfg = dataclasses.replace(cfg, combine=dataclasses.replace(cfg.combine, step=6),
                              suppress=dataclasses.replace(cfg.suppress, method="tophat"))
    detected = targets = false = 0
    for seed in (6, 7):
        frames, truth = simulate("wan2008", snr=5, rng=seed, n_frames=48, height=96,
                                 width=128, n_targets=2, directions=(30.0, 200.0))
        out = detect_sequence(frames, cfg)
        assert out["candidates"]["combined_frame"].max() == 6  # windows at 0, 6, ..., 36
        m = _score(out, frames, truth, cfg)
        detected, targets, false = (detected + m["detected"], targets + m["targets"],
                                    false + m["false"])
    assert targets == 28 and detected >= 0.9 * targets and false == 0


@pytest.mark.parametrize("size", [(213, 251), (100, 80), (37, 41)])
def test_frames_of_any_size_are_processed(size):
    h, w = size
    for seed in (1, 2):
        frames, truth = simulate("wan2008", snr=5, rng=seed, n_frames=36, height=h, width=w,
                                 n_targets=1, directions=(30.0,), margin=4.0)
        m = _score(detect_sequence(frames), frames, truth)
        assert m["detected"] >= 2 and m["false"] == 0


def test_too_few_frames_says_how_many(tmp_path):
    frames, _ = simulate("wan2008", rng=0, n_frames=11, height=40, width=40, n_targets=1,
                         directions=(45.0,))
    assert min_frames() == 36
    with pytest.raises(ValueError, match="has 11 frames; detection needs at least 12"):
        detect_sequence(frames)
    seq = tmp_path / "short.h5"
    write_sequence(seq, frames)
    with pytest.raises(InputError, match="needs at least 12"):
        process_file(seq, tmp_path / "out.h5")
    assert not (tmp_path / "out.h5").exists()
    with pytest.raises(ValueError, match="has 1 frame; detection"):
        detect_sequence(frames[:1])


@pytest.mark.parametrize("n_frames, length", [(36, 12), (35, 11), (30, 10), (20, 6), (12, 4)])
def test_short_sequences_run_with_shorter_combined_frames(n_frames, length):
    cfg = fit_config(ProcessConfig(), n_frames)
    assert (cfg.combine.length, cfg.combine.step) == (length, length)
    assert dataclasses.replace(cfg, combine=ProcessConfig().combine) == ProcessConfig()


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_30_frame_sequence_is_processed_and_flagged(tmp_path, seed):
    frames, truth = simulate("wan2008", snr=5, rng=seed, n_frames=30, height=96, width=128,
                             n_targets=2, directions=(30.0, 200.0))
    seq = tmp_path / "clip.h5"
    write_sequence(seq, frames, truth=truth)
    process_file(seq, tmp_path / "out.h5")
    res = read_results(tmp_path / "out.h5")
    assert res.attrs["short_sequence"] and res.attrs["combined_length"] == 10
    assert res.attrs["configured_length"] == 12 and res.config["combine"]["length"] == 10
    m = score_detections(res["detections"], truth, n_frames=30, length=10, step=10,
                         shape=frames.shape[1:], gate=3.0)
    assert m["targets"] == 6 and m["detected"] >= 5 and m["false"] == 0
    from irdetect.commands.info import describe
    assert "a short sequence of 30 frames: 12 configured" in "\n".join(describe(tmp_path / "out.h5"))


@pytest.mark.parametrize("kind", ["zero", "constant", "nan", "hot-once", "hot-always"])
def test_degenerate_sequences_do_not_crash(kind):
    frames = np.zeros((36, 48, 64), np.float32)
    if kind == "constant":
        frames += 100
    elif kind == "nan":
        frames = np.random.default_rng(0).normal(50, 3, frames.shape).astype(np.float32)
        frames[5] = np.nan
        frames[20, 10:20, 10:20] = np.nan
    elif kind == "hot-once":
        frames[17, 20, 30] = 255
    elif kind == "hot-always":
        frames[:, 20, 30] = 255
    out = detect_sequence(frames)
    for name in ("candidates", "detections", "segments", "tracks"):
        assert out[name].dtype == tables.BY_NAME[name]
    # a hot pixel in one frame is never confirmed; a pixel hot all the time is still
    # clutter for the temporal background; flat and NaN frames give nothing
    assert len(out["detections"]) == 0
    assert np.isfinite(out["candidates"]["x"]).all()


def test_progress_bar_and_iterator_order(capsys):
    frames, _ = simulate("wan2008", snr=4, rng=1, n_frames=48, height=64, width=64, n_targets=1, directions=(45.0,))
    chunks = list(iter_results(frames, progress=True))
    assert [int(c["candidates"]["combined_frame"][0]) if len(c["candidates"]) else k
            for k, c in enumerate(chunks)] == [0, 1, 2, 3]


def test_real_sequence_easy1():
    from conftest import real_sequence
    from irdetect.io import open_sequence, read_point_annotations

    folder = real_sequence("easy1")
    with open_sequence(folder / "frames") as src:
        frames = src[:]
    truth = read_point_annotations(folder / "truth.txt", len(frames))
    # easy1's target holds still in the scene (0.5 px per 12 frames against the
    # background) while the camera drifts; the default ("auto" -> registered, issue 8)
    # rightly treats it as scene-static structure, so this test pins the temporal
    # suppressor, which sees it move in the image
    config = ProcessConfig()
    config = dataclasses.replace(config, suppress=dataclasses.replace(config.suppress,
                                                                     method="temporal"))
    out = detect_sequence(frames, config)
    m = score_detections(out["detections"], truth, n_frames=len(frames), length=12, step=12,
                         shape=frames.shape[1:], gate=5.0)   # gate of its README
    assert m["targets"] == 3 and m["detected"] >= 2
    assert m["false_per_window"] <= 1.0


def test_low_snr_targets_found_by_the_matched_filter_verification():
    # wan2008 at SNR 2: the chains' matched-filter verification (the default) finds most
    # target-windows with no false detection; without it (the earlier front end: k 3.5,
    # mean point score >= 5) most are lost
    previous = ProcessConfig()
    previous = dataclasses.replace(
        previous, detect=dataclasses.replace(previous.detect, k=3.5),
        correlate=dataclasses.replace(previous.correlate, verify=0.0, min_score=5.0,
                                      max_deviation=5.0, tolerance=2.0))
    found = {"verified": 0, "previous": 0}
    targets = 0
    for seed in (1, 2):
        frames, truth = simulate("wan2008", snr=2, rng=seed)
        m = _score(detect_sequence(frames), frames, truth)
        assert m["false"] == 0
        found["verified"] += m["detected"]
        targets += m["targets"]
        found["previous"] += _score(detect_sequence(frames, previous), frames, truth)["detected"]
    assert found["verified"] >= 0.8 * targets
    assert found["previous"] < found["verified"] - 0.2 * targets


def _scene_score(seed, **kw):
    frames, truth = simulate("wan2008", rng=seed, n_frames=36, height=200, width=240,
                             n_targets=2, directions=[], margin=4.0, **kw)
    out = detect_sequence(frames)
    return _score(out, frames, truth), out


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_fast_target_is_found_by_the_fast_band(seed):
    # 4 px/frame: beyond the paper's merit (1 px/frame) and chains (2 px/frame)
    m, out = _scene_score(seed, snr=5.0, speed=[4.0, 4.0])
    assert m["targets"] == 6 and m["detected"] >= 5 and m["false"] <= 1
    assert (out["candidates"]["band"][out["candidates"]["confirmed"]] == 1).any()
    # the paper's band alone misses them; the per-frame path alone finds them too
    config = ProcessConfig()
    without = dataclasses.replace(config, fast=dataclasses.replace(config.fast, radius=0),
                                  frame=dataclasses.replace(config.frame, enabled=False))
    frames, truth = simulate("wan2008", rng=seed, n_frames=36, height=200, width=240,
                             n_targets=2, directions=[], margin=4.0, snr=5.0,
                             speed=[4.0, 4.0])
    assert _score(detect_sequence(frames, without), frames, truth)["detected"] <= 2
    frame_only = dataclasses.replace(without, frame=config.frame)
    out = detect_sequence(frames, frame_only)
    assert _score(out, frames, truth)["detected"] >= 5
    assert (out["detections"]["path"] & 2).all()


PANNING = dict(snr=5.0, speed=[0.5, 1.5], camera_pan=[1.6, -1.2], camera_jitter=0.5,
               cloud_amplitude=30.0, cloud_drift=[0.0, 0.0])


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_targets_are_found_through_a_panning_shaking_camera(seed):
    from irdetect.simulate.sequence import camera_offsets, load_scenario, target_paths

    m, out = _scene_score(seed, **PANNING)
    assert m["targets"] == 6 and m["detected"] >= 5 and m["false"] <= 1
    # the camera's offsets as the simulator drew them (faint clouds under noise: the
    # estimate is within about 0.6 px rms, 1.7 px at worst on these seeds)
    s = load_scenario("wan2008", n_frames=36, height=200, width=240, n_targets=2,
                      directions=[], margin=4.0, **PANNING)
    rng = np.random.default_rng(seed)
    target_paths(s, rng)
    truth = camera_offsets(s, rng)
    cam = np.column_stack([out["camera"]["dx"], out["camera"]["dy"]])
    assert np.sqrt(((cam - truth) ** 2).mean()) < 1.0 and np.abs(cam - truth).max() < 2.0


def test_band_2_runs_where_the_camera_outruns_the_papers_merit():
    from irdetect.pipeline.combined import camera_outruns

    t = np.arange(12.0)[:, None]
    assert not camera_outruns(t * [0.1, 0.05], 1)      # offsets that follow drifting clouds
    assert not camera_outruns(np.zeros((12, 2)), 1)
    assert camera_outruns(t * [0.4, 0.4], 1)           # 0.57 px/frame
    assert camera_outruns(t * [-4.0, 1.0], 1) and not camera_outruns(t * [-4.0, 1.0], 9)


@pytest.mark.parametrize("seed", [1, 3])
def test_a_target_slow_in_the_scene_under_a_fast_pan_is_band_2s(seed):
    # 0.2 px/frame against clouds that pan 4 px/frame: 4 px/frame in the image, past the
    # paper's band in image coordinates; too dim (SNR 3) for the fast band's point test
    # and too slow in the scene for the per-frame path's motion test. The paper's band
    # following the camera (band 2, ``fast.scene``) integrates it as it would a target
    # the camera holds
    from irdetect.config import FastConfig

    frames, truth = simulate("clutter", rng=seed, n_frames=48, height=256, width=384,
                             n_targets=1, snr=3.0, speed=(0.2, 0.2), camera_pan=(4.0, 1.0))
    out = detect_sequence(frames)
    m = _score(out, frames, truth)
    assert m["targets"] == 4 and m["detected"] == 4 and m["false"] == 0
    without = dataclasses.replace(ProcessConfig(), fast=FastConfig(scene=False))
    assert _score(detect_sequence(frames, without), frames, truth)["detected"] == 0


@pytest.mark.parametrize("seed", [1, 2])
def test_tracks_through_a_panning_camera_follow_their_targets(seed):
    from irdetect.initiate import positions_at, track_positions
    from irdetect.metrics.initiation import score_track_paths

    frames, truth = simulate("wan2008", rng=seed, n_frames=60, height=240, width=320,
                             n_targets=2, directions=[], margin=4.0, **PANNING)
    out = detect_sequence(frames)
    tracks = out["tracks"]
    assert tracks["scene"].any()                  # straight in the scene, not the image
    s = score_track_paths(tracks, truth, gate=6.0, camera=out["camera"])
    assert s["pt_overall"] == 1.0 and s["n_false"] == 0
    # a scene track's positions follow the camera: without it they drift off by its pan
    row = tracks[tracks["scene"]][:1]
    f = np.array([row["frame_start"][0], row["frame_end"][0]])
    moved = track_positions(row, f, out["camera"])[0]
    flat = row.copy()
    flat["scene"] = False
    drift = track_positions(flat, f)[0]
    span = f[1] - f[0]
    assert np.hypot(*(moved[1] - drift[1])) > 0.5 * span * np.hypot(1.6, 1.2)
    with pytest.raises(ValueError, match="camera"):
        track_positions(row, f)
    # pairs of (track, frame) give what the full table gives on its diagonal
    both = np.concatenate([row, flat])
    pairs = positions_at(both, f, out["camera"])
    full = track_positions(both, f, out["camera"])
    assert np.array_equal(pairs, full[[0, 1], [0, 1]])


def test_no_detection_is_reported_outside_the_image_and_its_track_keeps_it():
    # six targets crossing a 200x160 frame that pans 3 px/frame: three windows' tracks
    # put the target outside the image at the window's middle frame (it entered later or
    # left earlier), which were reported as detections there before; their votes still
    # start the tracks
    from irdetect.metrics.initiation import score_track_paths

    frames, truth = simulate("wan2008", rng=2, n_frames=60, height=160, width=200,
                             n_targets=6, snr=8.0, psf_sigma=1.0, speed=(1.0, 1.0),
                             camera_pan=(0.0, -3.0), cloud_amplitude=20.0, margin=4.0)
    out = detect_sequence(frames)
    d = out["detections"]
    assert len(d) >= 20
    assert ((d["x"] >= -0.5) & (d["x"] <= 199.5) & (d["y"] >= -0.5) & (d["y"] <= 159.5)).all()
    s = score_track_paths(out["tracks"], truth, gate=6.0, camera=out["camera"])
    assert len(out["tracks"]) == 6 and s["n_false"] == 0


@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize("speed", [0.5, 3.0])
def test_a_7x7_px_target_is_found(seed, speed):
    # PSF sigma 1.5 px: 7 x 7 px above a tenth of the peak (the SIRST "small" target)
    m, _ = _scene_score(seed, snr=5.0, psf_sigma=1.5, speed=[speed, speed])
    assert m["targets"] == 6 and m["detected"] >= 5 and m["false"] <= 1


@pytest.mark.parametrize("seed", [0, 2])
def test_long_memory_keeps_a_target_that_stops_detected(seed):
    # wan2008's 5 targets at SNR 5 stop in the scene at frame 30 and hover; the 12-frame
    # background learns them, the long memory (the first frames of 8 earlier windows of
    # the still camera) does not: windows 4-5 (frames 48-71) find them only with it
    frames, truth = simulate("wan2008", n_frames=84, snr=5, stop_frame=30, rng=seed)
    late = truth[(truth["frame"] >= 48) & (truth["frame"] < 72)]
    found = {}
    for memory in (0, 8):
        config = ProcessConfig()
        config = dataclasses.replace(config, suppress=dataclasses.replace(
            config.suppress, long_memory=memory))
        det = detect_sequence(frames, config)["detections"]
        det = det[(det["combined_frame"] >= 4) & (det["combined_frame"] <= 5)]
        found[memory] = score_detections(det, late, n_frames=84, length=12, step=12,
                                         shape=frames.shape[1:], gate=3.0)
    assert found[0]["detected"] == 0
    assert found[8]["detected"] >= 4 and found[8]["false"] == 0
    assert np.all(np.diff(truth[truth["target"] == 0]["x"][30:]) == 0)   # they hover


def test_the_detections_do_not_depend_on_the_sensors_units():
    """The same scene in other units (a gain of 257 as uint16, 0.01 as float32, an offset
    of 1000) gives the same detections and camera: every level is measured from the data
    (the 17 real folders so converted meet the goal on the same 11, a scratch run)."""
    base, _ = simulate("wan2008", rng=1, n_frames=36, height=200, width=240, n_targets=2,
                       directions=[], margin=4.0, **PANNING)        # uint8, 52-104
    ref = detect_sequence(base)
    assert len(ref["detections"]) >= 4
    for other in (base.astype(np.uint16) * 257, base.astype(np.float32) * np.float32(0.01),
                  base.astype(np.uint16) + 1000):
        out = detect_sequence(other)
        assert len(out["detections"]) == len(ref["detections"])
        for key in ("x", "y", "snr"):
            np.testing.assert_allclose(out["detections"][key], ref["detections"][key],
                                       rtol=1e-3, atol=1e-3)
        for key in ("dx", "dy"):
            np.testing.assert_allclose(out["camera"][key], ref["camera"][key], atol=1e-3)


def test_frames_repeated_by_a_frame_rate_conversion_are_named(caplog):
    """Every 5th frame shown twice (a 25 frames/s sensor captured at 30): one warning naming
    them from process's reader, and the tracker's note that it tracked the new frames
    (``irdetect.repeats``); a lone repeat, as recordings hold now and then, and a still
    image say nothing."""
    from irdetect.track import track

    frames, _ = simulate("wan2008", snr=6, n_targets=1, n_frames=40, height=64, width=64,
                         rng=2)
    converted = frames[np.concatenate([[t, t] if t % 5 == 4 else [t] for t in range(40)])]
    lone = frames[np.r_[0:10, 9, 10:40]]
    still = np.repeat(frames[:1], 40, axis=0)
    for clip, want in ((converted, 8), (lone, 0), (still, 0)):
        caplog.clear()
        with caplog.at_level(logging.INFO, logger="irdetect"):
            out = detect_sequence(clip)
            track(clip)
        if want:        # /camera marks them (the per-frame path's chains skip them)
            assert np.flatnonzero(out["camera"]["repeated"]).tolist() == list(range(5, 48, 6))
        said = [(r.levelno, r.getMessage()) for r in caplog.records
                if "repeat the frame" in r.getMessage()]
        assert len(said) == (2 if want else 0), said
        if want:
            assert said[0][0] == logging.WARNING
            assert said[0][1].startswith(f"{want} frames (5, 11, 17, 23, 29 and 3 more)")
            assert said[1] == (logging.INFO, f"{want} of 48 frames repeat the frame before "
                               "them exactly (a frame-rate conversion): tracked on the 40 "
                               "new frames (docs/tracking.md)")
