"""The per-frame path (issue 26): CFAR peaks, per-frame tracks, their fusion with the
combined-frame path, the shared score and the operating point."""

import dataclasses

import numpy as np
import pytest

from irdetect import tables
from irdetect.config import ProcessConfig
from irdetect.metrics.detection import roc, score_detections
from irdetect.operating import tail_threshold
from irdetect.peaks import cfar_level, frame_level, frame_peaks
from irdetect.pipeline import detect_sequence
from irdetect.pipeline.fusion import fuse_paths, initiate_tracks
from irdetect.pipeline.perframe import frame_tracks
from irdetect.simulate import simulate

FRAME_ONLY_OFF = dataclasses.replace(ProcessConfig().frame, enabled=False)


def _score(out, frames, truth, gate=3.0):
    return score_detections(out["detections"], truth, n_frames=len(frames), length=12,
                            step=12, shape=frames.shape[1:], gate=gate)


def test_cfar_level_is_the_gaussian_tail():
    # 1 false peak per frame of 256 x 256 px: Q(k) = 1 / 65536
    assert cfar_level(65536, 1.0) == pytest.approx(4.1696, abs=1e-3)
    assert cfar_level(65536, 1.0, 0.05) > cfar_level(65536, 1.0)
    for bad in (0.0, -1.0, np.nan, 1e6):
        with pytest.raises(ValueError, match="false_rate"):
            cfar_level(65536, bad)


@pytest.mark.parametrize("rate", [1.0, 0.1])
def test_cfar_on_a_noise_only_sequence_gives_the_stated_rate(rate):
    # white noise through the whole front end (temporal background, matched filter,
    # standardisation): the measured false peaks per frame within a factor 2 of the stated
    frames, truth = simulate("wan2008", rng=11, n_frames=240, height=128, width=160,
                             n_targets=0)
    assert len(truth) == 0
    config = ProcessConfig()
    config = dataclasses.replace(config, frame=dataclasses.replace(config.frame,
                                                                   false_rate=rate))
    out = detect_sequence(frames, config)
    measured = len(out["frame_detections"]) / len(frames)
    assert rate / 2 <= measured <= 2 * rate, measured
    # and no per-frame track, detection or track comes of them
    assert not out["frame_tracks"]["kept"].any()
    assert not (out["detections"]["path"] & tables.PATH_FRAME).any()


def test_frame_peaks_are_local_maxima_with_sub_pixel_positions():
    yy, xx = np.mgrid[0:40, 0:50].astype(np.float32)
    blob = 9.0 * np.exp(-((xx - 20.3) ** 2 + (yy - 12.7) ** 2) / (2 * 1.0 ** 2))
    weak = 3.0 * np.exp(-((xx - 40.0) ** 2 + (yy - 30.0) ** 2) / 2.0)
    m = (blob + weak).astype(np.float32)
    p = frame_peaks([m, np.zeros_like(m)], 5.0, first_frame=7)
    assert len(p) == 1 and p["frame"][0] == 7
    assert abs(p["x"][0] - 20.3) < 0.1 and abs(p["y"][0] - 12.7) < 0.1
    assert p["score"][0] == pytest.approx(m[13, 20])
    # the strongest max_peaks of a frame
    many = np.zeros((40, 50), np.float32)
    many[4:36:7, 4:50:7] = np.arange(35, dtype=np.float32).reshape(5, 7) + 10
    top = frame_peaks([many], 5.0, max_peaks=5)
    assert sorted(top["score"]) == [40.0, 41.0, 42.0, 43.0, 44.0]
    # a ridge (an edge the background left) is no point: nothing on it is a peak
    ridge = np.zeros((40, 50), np.float32)
    ridge[20, :] = 10.0
    ridge[20, 25] = 10.5
    assert len(frame_peaks([ridge], 5.0)) == 0
    with pytest.raises(ValueError, match="max_peaks"):
        frame_peaks([many], 5.0, max_peaks=0)


def test_tail_threshold_follows_the_clutter_sample():
    rng = np.random.default_rng(3)
    clutter = 5.0 + rng.exponential(2.0, 400)            # 400 clutter scores, 100 frames
    t = tail_threshold(clutter, 100, 0.01, floor=5.0)
    # an exponential tail of scale 2 above 5: N(s) = 400 exp(-(s - 5) / 2) = 1 at s = 17
    assert 15.5 < t < 18.5
    assert tail_threshold(clutter[:14], 100, 0.01, floor=5.0) == 5.0  # too few to fit
    assert tail_threshold(clutter[:50], 10_000, 0.01, floor=5.0) == 5.0  # within the rate
    with pytest.raises(ValueError, match="rate"):
        tail_threshold(clutter, 100, 0.0, floor=5.0)


def _blob_peaks(n_frames, blobs, shape, rng):
    """Peaks of standardised noise frames with blobs (x0, y0, vx, vy, amplitude) moving
    from (x0, y0) at (vx, vy) px/frame."""
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    frames = []
    for t in range(n_frames):
        f = rng.normal(0, 1, shape).astype(np.float32)
        for x0, y0, vx, vy, amplitude in blobs:
            x, y = x0 + vx * t, y0 + vy * t
            f += amplitude * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / 2.0).astype(np.float32)
        frames.append(f)
    return frame_peaks(frames, frame_level(shape, 1.0))


def _tracks(peaks, shape, pan=0.0, **kw):
    """``frame_tracks`` over 3 windows of 12 frames, the camera panning ``pan`` px/frame in x
    (``kw``: more of its keywords)."""
    camera = tables.from_columns(tables.CAMERA, frame=np.arange(36), dx=pan * np.arange(36),
                                 dy=np.zeros(36))
    return frame_tracks(peaks, camera, [0, 12, 24], 12, shape=shape, n_frames=36,
                        level=frame_level(shape, 1.0), **kw)


def test_the_per_frame_path_alone_tracks_a_fast_target_and_not_the_noise():
    rng = np.random.default_rng(5)
    shape = (128, 256)
    peaks = _blob_peaks(36, [(20.0, 30.0, 6.0, 2.0, 9.0)], shape, rng)
    ft = _tracks(peaks, shape)
    kept = ft[ft["kept"]]
    assert sorted(kept["combined_frame"]) == [0, 1, 2]
    mid = np.array([5.5, 17.5, 29.5])
    assert np.allclose(kept["x"], 20.0 + 6.0 * mid, atol=0.5)
    assert np.allclose(kept["y"], 30.0 + 2.0 * mid, atol=0.5)
    assert np.allclose(kept["vx"], 6.0, atol=0.2) and np.allclose(kept["vy"], 2.0, atol=0.2)
    assert (kept["score"] > 5).all() and (kept["expectation"] < 0.012).all()
    # under a camera panning 4 px/frame the same target in the image (2 px/frame against
    # the scene) is the same track, its scene velocity the difference
    ft = _tracks(peaks, shape, pan=4.0)
    kept = ft[ft["kept"]]
    assert len(kept) == 3 and np.allclose(kept["svx"], 2.0, atol=0.2)
    assert np.allclose(kept["vx"], 6.0, atol=0.2)


def test_repeated_frames_are_no_scans_of_the_per_frame_path():
    # every 5th frame shown twice (a frame-rate conversion): the peaks of frames 0..35 of a
    # target at 4 px/frame, with those of frames 4, 9, ... repeated (frame 5 shows frame 4)
    rng = np.random.default_rng(6)
    shape = (128, 256)
    peaks = _blob_peaks(30, [(20.0, 30.0, 4.0, 1.0, 9.0)], shape, rng)
    shown = np.repeat(np.arange(30), np.where(np.arange(30) % 5 == 4, 2, 1))[:36]
    rows = [peaks[peaks["frame"] == f] for f in shown]
    for t, r in enumerate(rows):
        r["frame"] = t
    peaks = np.concatenate(rows)
    repeated = np.r_[False, shown[1:] == shown[:-1]]
    camera = tables.from_columns(tables.CAMERA, frame=np.arange(36), dx=np.zeros(36),
                                 dy=np.zeros(36), repeated=repeated)

    def kept(camera):
        ft = frame_tracks(peaks, camera, [0, 12, 24], 12, shape=shape, n_frames=36,
                          level=frame_level(shape, 1.0))
        return ft[ft["kept"]]

    got = kept(camera)
    assert sorted(got["combined_frame"]) == [0, 1, 2]
    # velocities per input frame: 4 px per new frame, 10 new frames in 12 input frames
    # (11 for the first window's 12: its 12th frame repeats its 11th)
    assert np.allclose(got["vx"], 4.0 * 10 / 12, atol=0.2), got["vx"]
    # at each window's middle frame, where the frame shown puts the target
    want = 20.0 + 4.0 * np.interp([5.5, 17.5, 29.5], np.arange(36), shown)
    assert np.abs(got["x"] - want).max() < 0.5, (got["x"], want)
    # taken as scans, the stops pull the chains' lines off (1.7 px here) or break them
    plain = kept(tables.from_columns(tables.CAMERA, frame=np.arange(36), dx=np.zeros(36),
                                     dy=np.zeros(36)))
    assert len(plain) < 3 or np.abs(plain["x"] - want).max() > 1.0


def test_structure_that_stays_put_in_the_scene_is_not_a_per_frame_track():
    rng = np.random.default_rng(6)
    shape = (96, 96)
    ft = _tracks(_blob_peaks(36, [(40.0, 50.0, 0.0, 0.0, 12.0)], shape, rng), shape)
    assert len(ft) >= 3 and not ft["moving"].any() and not ft["kept"].any()


def test_a_fast_target_no_brighter_than_static_clutter_is_judged_by_its_chain():
    # 24 bright points that stay put (amplitudes 8-16) set the score level of test 3 above
    # a target of amplitude 9 at 6 px/frame and a point drifting 0.8 px/frame (structure
    # seen through a registration error); the slow one must still reach that level, the
    # fast one is kept on its chain (its 12 hits on a line)
    rng = np.random.default_rng(0)
    shape = (128, 256)
    sx, sy, amp = rng.uniform(10, 246, 24), rng.uniform(10, 118, 24), rng.uniform(8, 16, 24)
    static = [(x, y, 0.0, 0.0, a) for x, y, a in zip(sx, sy, amp)]
    peaks = _blob_peaks(36, static + [(20.0, 40.0, 6.0, 1.0, 9.0), (100.0, 100.0, 0.8, 0.0, 9.0)],
                        shape, rng)
    ft = _tracks(peaks, shape)
    speed = np.hypot(ft["svx"], ft["svy"])
    fast, slow = np.abs(speed - 6.08) < 0.3, np.abs(speed - 0.8) < 0.3
    assert ft["kept"][fast].sum() == 3 and not ft["kept"][~fast].any()
    assert (ft["moving"][slow] & (ft["expectation"][slow] < 0.012)).any()  # tests 1-2 pass
    assert not _tracks(peaks, shape, clutter_speed=np.inf)["kept"].any()   # all lost                 # the level on every track: lost


def _det(x, y, k, path=tables.PATH_COMBINED, snr=5.0):
    return tables.from_columns(tables.DETECTION, x=[x], y=[y], frame_start=[12 * k],
                               frame_end=[12 * k + 11], combined_frame=[k], path=[path],
                               snr=[snr], support=[0.5], score=[snr], intensity=[snr],
                               vx=[0.0], vy=[0.0], n_members=[4])


def _ft(x, y, k, score=20.0):
    return tables.from_columns(tables.FRAME_TRACK, x=[x], y=[y], frame_start=[12 * k],
                               frame_end=[12 * k + 11], combined_frame=[k], vx=[5.0],
                               vy=[0.0], svx=[5.0], svy=[0.0], n_points=[12], score=[score],
                               expectation=[0.0], moving=[True], kept=[True])


def test_fusion_gives_one_row_per_target_and_says_which_path():
    comb = np.concatenate([_det(50.0, 50.0, 0), _det(100.0, 20.0, 0), _det(53.0, 51.0, 1),
                           _det(75.0, 52.0, 1), _det(57.0, 60.0, 1)])
    ft = np.concatenate([_ft(52.0, 50.0, 0), _ft(150.0, 80.0, 0), _ft(55.0, 51.0, 1)])
    ft_dropped = _ft(10.0, 10.0, 1)
    ft_dropped["kept"] = False
    out = fuse_paths(comb, np.concatenate([ft, ft_dropped]))
    w0, w1 = out[out["combined_frame"] == 0], out[out["combined_frame"] == 1]
    # window 0: one target seen by both (the per-frame position), one per path alone
    assert sorted(w0["path"].tolist()) == [1, 2, 3]
    both = w0[w0["path"] == 3]
    assert both["x"][0] == 52.0 and both["snr"][0] == 20.0
    # window 1: three combined detections near one per-frame track (5 px/frame): one
    # pairs, one 20 px along its path is a piece of its streak (dropped), one 9 px off
    # the path stays
    assert sorted(w1["path"].tolist()) == [1, 3] and len(w1) == 2
    assert w1[w1["path"] == 1]["y"][0] == 60.0
    assert 10.0 not in out["x"]                          # a track not kept adds nothing
    # the combined-frame path alone: its rows unchanged
    assert fuse_paths(comb, tables.empty(tables.FRAME_TRACK)).tobytes() == comb.tobytes()


def test_a_fast_target_under_a_panning_camera():
    # 3 px/frame against a cloudy scene that pans 5 px/frame: 8 px/frame in the image,
    # past the paper's band; the per-frame path follows it in scene coordinates
    frames, truth = simulate("clutter", rng=4, n_frames=48, height=256, width=384,
                             n_targets=1, snr=8.0, speed=(3.0, 3.0), directions=(0.0,),
                             camera_pan=(5.0, 0.0))
    out = detect_sequence(frames)
    assert _score(out, frames, truth)["pd"] == 1.0
    # every window's target is the per-frame path's too, and nothing it reports is false
    # (the combined-frame path's own rows include a chain near the border the panning
    # scene leaves: 3 false detections here, docs/detection.md)
    mine = out["detections"][(out["detections"]["path"] & tables.PATH_FRAME) > 0]
    assert len(mine) == 4 and _score({"detections": mine}, frames, truth)["false"] == 0
    kept = out["frame_tracks"][out["frame_tracks"]["kept"]]
    assert np.allclose(kept["svx"], 3.0, atol=0.3) and np.allclose(kept["vx"], 8.0, atol=0.3)


def test_dim_slow_targets_stay_the_combined_paths():
    # SNR 2 at 1 px/frame: too dim for any single frame, found by integration; the
    # per-frame path adds nothing false
    frames, truth = simulate("wan2008", snr=2.0, rng=3)
    out = detect_sequence(frames)
    m = _score(out, frames, truth)
    off = _score(detect_sequence(frames, dataclasses.replace(ProcessConfig(),
                                                             frame=FRAME_ONLY_OFF)),
                 frames, truth)
    assert m["detected"] >= off["detected"] and m["false"] <= off["false"]
    assert (out["detections"]["path"] & tables.PATH_COMBINED).all()


def test_roc_ranks_by_the_shared_score():
    truth = tables.from_columns(tables.TRUTH, frame=np.arange(24), target=np.zeros(24),
                                x=np.full(24, 30.0), y=np.full(24, 30.0))
    det = np.concatenate([_det(30.0, 30.0, 0, snr=9.0), _det(30.0, 30.0, 1, snr=4.0),
                          _det(80.0, 10.0, 0, snr=6.0), _det(70.0, 70.0, 1, snr=3.0)])
    curve = roc(det, truth, n_frames=24, length=12, step=12, shape=(100, 100))
    assert curve["thresholds"] == [9.0, 6.0, 4.0, 3.0]
    assert curve["pd"] == [0.5, 0.5, 1.0, 1.0]
    assert curve["false_per_frame"] == pytest.approx([0, 1 / 24, 1 / 24, 2 / 24])
    # Pd 0.5 from 0 false per frame, 1.0 from 1/24: area (0.5 x 1/24 + 1.0 x (0.1 - 1/24))
    assert curve["auc"] == pytest.approx((0.5 / 24 + (0.1 - 1 / 24)) / 0.1, abs=0.01)


def test_results_say_the_path_of_every_detection_and_track(tmp_path):
    from irdetect.io import read_results, write_sequence
    from irdetect.pipeline import process_file

    frames, truth = simulate("wan2008", snr=6.0, rng=2, n_frames=48, height=128, width=192,
                             n_targets=2, directions=(0.0, 90.0), speed=(4.0, 4.0))
    write_sequence(tmp_path / "s.h5", frames, truth=truth)
    process_file(tmp_path / "s.h5", tmp_path / "r.h5")
    r = read_results(tmp_path / "r.h5")
    for name in ("detections", "combined_detections", "frame_detections", "frame_tracks",
                 "tracks"):
        assert r[name].dtype == tables.BY_NAME[name]
    assert set(np.unique(r["detections"]["path"])) <= {1, 2, 3}
    assert (r["tracks"]["path"] > 0).all() and len(r["tracks"]) >= 2
    assert np.isfinite(r["detections"]["snr"]).all()


def _windows(x, y):
    k = np.arange(len(x))
    return tables.from_columns(tables.DETECTION, x=np.asarray(x, float),
                               y=np.asarray(y, float), frame_start=12 * k,
                               frame_end=12 * k + 11, combined_frame=k)


def test_a_turning_target_is_one_track_and_two_crossing_targets_are_two():
    # 3 px/frame on an arc turning 10 degrees per combined frame: no line holds all 5
    # detections; of two segments of 3 that share the middle one the second has only 2
    # of its own, fewer than a Hough cell needs
    a = np.radians(10.0) * np.arange(5)
    r = 36.0 / np.radians(10.0)
    turning = _windows(100 + r * np.sin(a), 300 - r * (1 - np.cos(a)))
    tracks = initiate_tracks(turning, ProcessConfig())
    assert len(tracks) == 1 and tracks["n_points"][0] == 3
    # two straight targets crossing in window 2 (their detections there 1 px apart)
    k = np.arange(5.0)
    crossing = np.concatenate([_windows(100 + 36 * k, 200 + 0 * k),
                               _windows(172 + 0 * k + 0.5, 128 + 36 * k + 1.0)])
    tracks = initiate_tracks(crossing[np.argsort(crossing["combined_frame"], kind="stable")],
                             ProcessConfig())
    assert len(tracks) == 2 and set(tracks["n_points"]) == {5}


def test_two_detections_make_a_track_only_when_their_own_velocities_agree():
    # a short sequence asks for 2 votes; any two detections of two windows lie on a line,
    # so each detection's own velocity must agree with the line's
    det = _windows([100.0, 136.0], [50.0, 50.0])               # 3 px/frame along x
    det["vx"], det["vy"] = 3.0, 0.0
    config = ProcessConfig()
    tracks = initiate_tracks(det, config)
    assert len(tracks) == 1 and abs(tracks["vx"][0] - 3.0) < 0.05
    # the same two detections, each seen still (velocity 0): 1.5 px/frame x 5.5 frames
    # of disagreement is more than the 4.5-px gate
    still = det.copy()
    still["vx"] = 0.0
    assert len(initiate_tracks(still, config)) == 0
    # without velocities (NaN) the two positions alone decide, as before
    unknown = det.copy()
    unknown["vx"], unknown["vy"] = np.nan, np.nan
    assert len(initiate_tracks(unknown, config)) == 1
    # three detections on the line are a line of their own whatever their velocities
    three = _windows([100.0, 136.0, 172.0], [50.0, 50.0, 50.0])
    three["vx"], three["vy"] = 0.0, 0.0
    assert len(initiate_tracks(three, config)) == 1


def test_a_target_that_crosses_the_frame_in_a_few_windows_is_a_track_cut_to_the_frame():
    # 11 windows of 12 frames; a target at 5 px/frame crosses the 320-px frame in windows
    # 2-6 (5 detections, under the 0.6 x 10 votes of a line inside throughout), a line
    # inside in all 11 with 5 detections, and scattered points
    starts = 12 * np.arange(11)
    mid = starts + 5.5
    k = np.arange(2, 7)
    fast = _windows(-10.0 + 5.0 * mid[k], 60.0 + 0 * k)
    fast["combined_frame"] = k
    fast["frame_start"], fast["frame_end"] = starts[k], starts[k] + 11
    slow = _windows(100 + 1.0 * mid[:5], 150.0 + 0 * mid[:5])
    rng = np.random.default_rng(0)
    noise = _windows(rng.uniform(0, 319, 11), rng.uniform(0, 239, 11))
    det = np.concatenate([fast, slow, noise])
    det = det[np.argsort(det["combined_frame"], kind="stable")]
    config = ProcessConfig()
    assert len(initiate_tracks(det, config)) == 0              # the first pass alone
    tracks = initiate_tracks(det, config, shape=(240, 320), starts=starts, length=12)
    assert len(tracks) == 1 and tracks["n_points"][0] == 5
    t = tracks[0]
    assert abs(t["vx"] - 5.0) < 0.05 and abs(t["vy"]) < 0.05
    # its span, its windows' frames 24-83, is cut to those its line is inside the frame
    # in: x = -10 + 5 f <= 319 up to frame 65
    assert (t["frame_start"], t["frame_end"]) == (24, 65)
    assert abs(t["x0"] - 110.0) < 0.5


def _turning_scene(seed, n=60):
    # a bright point (peak 12 noise sigmas) at (2, 1) px/frame that turns to (1, 2.5)
    # px/frame after frame 47, as istd640-seq3-135's target does in its last window
    rng = np.random.default_rng(seed)
    f = np.arange(n, dtype=float)
    x = 100 + 2.0 * np.minimum(f, 47) + 1.0 * np.maximum(f - 47, 0)
    y = 100 + 1.0 * np.minimum(f, 47) + 2.5 * np.maximum(f - 47, 0)
    yy, xx = np.mgrid[:256, :256]
    frames = rng.normal(100, 2.0, (n, 256, 256)).astype(np.float32)
    frames += 24.0 * np.exp(-((xx - x[:, None, None]) ** 2 + (yy - y[:, None, None]) ** 2)
                            / (2 * 0.8 ** 2)).astype(np.float32)
    truth = np.zeros(n, tables.TRUTH)
    truth["frame"], truth["x"], truth["y"] = f, x, y
    return frames, truth


@pytest.mark.parametrize("seed", [1, 3])
def test_a_chain_does_not_report_a_bright_target_where_it_did_not_turn(seed):
    # a chain is straight over 3 windows: before, it went on where the target turned
    # (seed 1: a detection 12 px off in the last window) or reached back into windows
    # the later leg never crossed (seed 3: 27 and 9 px off, and a second track)
    frames, truth = _turning_scene(seed)
    out = detect_sequence(frames)
    m = _score(out, frames, truth)
    assert m["pd"] == 1.0 and m["false"] == 0
    assert len(out["tracks"]) == 1
