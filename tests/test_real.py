"""Real backgrounds (issue 8): the moving-camera suppressor, and the real DAUB data.

The simulated tests draw what the DAUB sequences show (a textured scene panning under a
camera that holds the target nearly still, hot pixels fixed in the image) and check that
the registered background removes the scene and the sensor pattern but keeps the target.
The real-data test reads ../shared/data/real/daub-data20 and is skipped when absent.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from irdetect.config import ProcessConfig, SuppressConfig
from irdetect.metrics.detection import score_detections
from irdetect.pipeline import detect_sequence
from irdetect.camera import estimate_motion
from irdetect.suppress import (camera_moves, future_frames, noise_sigma, past_frames,
                               suppress)

SIZE = 128


def panning_scene(n_frames=40, speed=(0.45, 0.3), target=(48.0, 40.0), drift=(0.25, 0.0),
                  amplitude=40.0, noise=2.0, hot=((20, 70), (75, 15)), rng=0):
    """Frames (T, SIZE, SIZE) of a textured scene moving by ``speed`` px/frame, a point
    target at ``target`` drifting by ``drift`` px/frame in the image, hot pixels fixed
    in the image; and the target's (x, y) per frame."""
    rng = np.random.default_rng(rng)
    big = SIZE + 64
    texture = cv2.GaussianBlur(rng.normal(0, 1, (big, big)).astype(np.float32), (0, 0), 2.0)
    texture = 100 + 10 * texture / texture.std()
    texture[big // 2:, :] += 30                       # a bright edge across the scene
    yy, xx = np.mgrid[:SIZE, :SIZE].astype(np.float32)
    frames = np.empty((n_frames, SIZE, SIZE), np.float32)
    pos = np.empty((n_frames, 2))
    for t in range(n_frames):
        # scene content moves by +speed t: sample the texture at (x - speed t + 32)
        mx = (xx + 32 - speed[0] * t).astype(np.float32)
        my = (yy + 32 - speed[1] * t).astype(np.float32)
        f = cv2.remap(texture, mx, my, cv2.INTER_LINEAR)
        tx, ty = target[0] + drift[0] * t, target[1] + drift[1] * t
        f += amplitude * np.exp(-((xx - tx) ** 2 + (yy - ty) ** 2) / (2 * 0.7 ** 2))
        f += rng.normal(0, noise, f.shape).astype(np.float32)
        for x, y in hot:
            f[y, x] += 80
        frames[t] = f
        pos[t] = tx, ty
    return frames, pos


def peak_z(residual, x, y, r=2):
    med = float(np.median(residual))
    sig = float(noise_sigma(residual))
    xi, yi = int(round(x)), int(round(y))
    return (residual[yi - r:yi + r + 1, xi - r:xi + r + 1].max() - med) / sig


def test_registered_keeps_target_and_removes_panning_scene():
    frames, pos = panning_scene()
    t = 30
    reg = suppress(frames, method="registered")
    tem = suppress(frames, method="temporal")
    z_reg = peak_z(reg[t], *pos[t])
    # away from the target: the strongest scene residue (a hot pixel counts as scene)
    away = np.ones((SIZE, SIZE), bool)
    x, y = np.round(pos[t]).astype(int)
    away[y - 6:y + 7, x - 6:x + 7] = False
    away[:4], away[-4:], away[:, :4], away[:, -4:] = False, False, False, False
    sig_reg = float(noise_sigma(reg[t]))
    sig_tem = float(noise_sigma(tem[t]))
    clutter_reg = (reg[t][away].max() - np.median(reg[t])) / sig_reg
    clutter_tem = (tem[t][away].max() - np.median(tem[t])) / sig_tem
    assert z_reg > 5 and clutter_reg < 0.6 * z_reg
    # the plain temporal background leaves the moving scene: its residue outshines
    # the target there
    assert clutter_tem > peak_z(tem[t], *pos[t])


def test_registered_removes_hot_pixels_fixed_in_the_image():
    frames, pos = panning_scene(hot=((30, 60),))
    res = suppress(frames, method="registered")
    assert abs(res[25, 60, 30]) < 10
    # the camera's offsets follow the scene, not the hot pixel (a flat spectrum, which
    # phase correlation's whitening favours, would pin them at 0; irdetect.camera
    # median-filters each frame first)
    c = estimate_motion(frames)
    assert np.abs(c - np.arange(40)[:, None] * np.array([0.45, 0.3])).max() < 0.3
    # without the fixed-pattern step the warped past frames carry the hot pixel to
    # where the scene was: a residue beside it
    raw = suppress(frames, method="registered", fixed_pattern=False)
    assert np.abs(raw[25, 55:66, 25:36]).max() > 3 * np.abs(res[25, 55:66, 25:36]).max()


def test_inputs_are_not_modified():
    # OpenCV 5.0's phaseCorrelate multiplies its window into its inputs; the suppressor
    # must hand it copies
    frames, _ = panning_scene(n_frames=24)
    before = frames.copy()
    suppress(frames[12:], previous=frames[:12], method="registered")
    suppress(frames, method="auto")
    estimate_motion(frames)
    assert np.array_equal(frames, before)


def test_camera_moves_tells_panning_from_still_noise():
    frames, _ = panning_scene(n_frames=20)
    assert camera_moves(estimate_motion(frames))
    still = np.random.default_rng(1).normal(100, 3, (20, 64, 64)).astype(np.float32)
    still[:, 30, 30] += 40
    assert not camera_moves(estimate_motion(still))
    assert not camera_moves(estimate_motion(np.zeros((5, 16, 16))))  # flat: no motion


def test_auto_is_temporal_for_a_still_camera():
    still = np.random.default_rng(2).normal(100, 3, (24, 48, 48)).astype(np.float32)
    a = suppress(still[12:], previous=still[:12], method="auto")
    b = suppress(still[12:], previous=still[:12], method="temporal")
    np.testing.assert_array_equal(a, b)


def test_streaming_equals_whole_sequence():
    frames, _ = panning_scene(n_frames=36)
    whole = suppress(frames, method="registered")
    keep = past_frames("registered", history=12, gap=8)
    block = suppress(frames[24:], previous=frames[24 - keep:24], method="registered")
    # same background frames and shifts; the fixed pattern is estimated from the frames
    # held, so allow its (small) difference
    assert np.abs(block - whole[24:])[:, 8:-8, 8:-8].mean() < 0.5


@pytest.mark.parametrize("kwargs, name", [({"gap": 0}, "gap"), ({"tolerance": -1}, "tolerance"),
                                          ({"samples": 0}, "samples")])
def test_bad_registered_parameters_are_named(kwargs, name):
    with pytest.raises(ValueError, match=name):
        suppress(np.zeros((3, 16, 16)), method="registered", **kwargs)


def test_pipeline_finds_camera_held_target_on_panning_scene():
    frames, pos = panning_scene(n_frames=48, amplitude=40.0, drift=(0.25, 0.1))
    truth = np.zeros(len(frames), dtype=[("frame", "<i8"), ("target", "<i8"),
                                         ("x", "<f8"), ("y", "<f8"), ("amplitude", "<f8")])
    truth["frame"] = np.arange(len(frames))
    truth["x"], truth["y"] = pos[:, 0], pos[:, 1]
    out = detect_sequence(frames)                 # defaults: "auto" -> registered
    m = score_detections(out["detections"], truth, n_frames=len(frames), length=12,
                         step=12, shape=frames.shape[1:], gate=3.0)
    # measured 4 of 4 (3 of 4 with the top-hat stand-in for the first `gap` frames,
    # ``suppress.lead_in = "tophat"``)
    assert m["targets"] == 4 and m["detected"] == 4
    assert m["false"] == 0


def _truth_of(pos):
    truth = np.zeros(len(pos), dtype=[("frame", "<i8"), ("target", "<i8"), ("x", "<f8"),
                                      ("y", "<f8"), ("amplitude", "<f8")])
    truth["frame"] = np.arange(len(pos))
    truth["x"], truth["y"] = pos[:, 0], pos[:, 1]
    return truth


def test_lead_in_future_keeps_first_frames_target_the_top_hat_loses():
    # the first `gap` frames have no registered past; the top-hat stand-in keeps the
    # scene's texture (narrower than 9 px: noise sigma 7 grey levels instead of 4) and
    # the target sinks in it; the registered background built from the frames after
    # them removes the texture as it does for every later frame
    frames, pos = panning_scene(n_frames=30, hot=())
    t = 3
    future = suppress(frames[:12], following=frames[12:27], method="registered")
    tophat = suppress(frames[:12], method="registered", lead_in="tophat")
    whole = suppress(frames, method="registered")
    assert peak_z(future[t], *pos[t]) > 6 > 4 > peak_z(tophat[t], *pos[t])
    assert noise_sigma(future[t]) < 0.7 * noise_sigma(tophat[t])
    # streaming (the window and the look-ahead frames) matches the whole sequence but
    # for the fixed pattern's estimate from fewer frames
    assert np.abs(future[t] - whole[t])[8:-8, 8:-8].mean() < 0.5
    assert future_frames("registered", 0, 12, history=12, gap=8) == 15
    assert future_frames("registered", 12, 24) == 0
    assert future_frames("registered", 0, 12, lead_in="tophat") == 0


def test_lead_in_future_finds_the_first_window_the_top_hat_misses():
    frames, pos = panning_scene(n_frames=48, amplitude=40.0, drift=(0.25, 0.1))
    truth = _truth_of(pos)
    found = {}
    for lead_in in ("future", "tophat"):
        config = ProcessConfig(suppress=SuppressConfig(lead_in=lead_in))
        det = detect_sequence(frames, config)["detections"]
        m = score_detections(det, truth, n_frames=len(frames), length=12, step=12,
                             shape=frames.shape[1:], gate=3.0)
        first = det[det["combined_frame"] == 0]
        found[lead_in] = bool(len(first)) and bool(
            (np.hypot(first["x"] - pos[:12, 0].mean(), first["y"] - pos[:12, 1].mean())
             <= 3.0).any())
        assert m["false"] == 0
    # measured: the top-hat stand-in misses window 0 (3 of 4), the look-ahead finds it
    assert found == {"future": True, "tophat": False}


@pytest.mark.parametrize("kwargs, name", [({"lead_in": "past"}, "lead_in"),
                                          ({"following": np.zeros((2, 8, 8))}, "following")])
def test_bad_lead_in_parameters_are_named(kwargs, name):
    with pytest.raises(ValueError, match=name):
        suppress(np.zeros((3, 16, 16)), method="registered", **kwargs)


#: (sequence, target-windows, fewest detected, most false detections per window, gate):
#: a little below the measured numbers (docs/results/real.md: daub-data20,
#: daub-data13-b, daub-data13-a and daub-data15-a 8/8 with no false detection, easy1 3/3
#: with none). 13-b had 3 false windows without the local test of verified tracks
#: (``correlate.verify_local``); easy1's broad target was lost when that test's ring came
#: closer than 5 px; 13-a's window 0 needs the look-ahead background of the first frames
#: (``suppress.lead_in``), 15-a's last windows ``correlate.max_speed`` 2, 14's first
#: window ``correlate.screen`` 0.4 (7/8 and 1 false at 0.5; 7/8 and 1 false again with
#: the camera's offsets measured once per frame against a keyframe instead of per lag:
#: they differ from the per-lag shifts by 0.06 px rms there, and the window is borderline)
REAL_FLOORS = (("daub-data20", 8, 7, 0.125, 3.0), ("daub-data13-b", 8, 7, 0.125, 3.0),
               ("daub-data13-a", 8, 7, 0.125, 3.0), ("daub-data15-a", 8, 7, 0.125, 3.0),
               ("daub-data14", 8, 7, 0.125, 3.0),
               ("easy1", 3, 3, 0.34, 5.0),
               # the operating point (``operating.false_rate``): seq3-135 and seq2-204 had
               # 23 and 10 false detections per window without it (1.0 and 0.8 with it);
               # data22-a's faint windows 1 and 2 (camera-held target) fell below a level
               # measured on 12 frames (5 of 8): the 36 of a chain keep them
               ("istd640-seq3-135", 5, 5, 1.2, 5.0), ("istd640-seq2-204", 5, 5, 1.2, 5.0),
               ("daub-data22-a", 8, 8, 0.125, 3.0))


@pytest.mark.parametrize("name, targets, floor_detected, ceiling_false, gate", REAL_FLOORS)
def test_real_sequence_default_config(name, targets, floor_detected, ceiling_false, gate):
    from conftest import real_sequence
    from irdetect.io import open_sequence, read_point_annotations

    folder = real_sequence(name)
    with open_sequence(folder / "frames") as src:
        frames = src[:]
    truth = read_point_annotations(folder / "truth.txt", len(frames))
    out = detect_sequence(frames, ProcessConfig())
    m = score_detections(out["detections"], truth, n_frames=len(frames), length=12, step=12,
                         shape=frames.shape[1:], gate=gate)    # gates of the READMEs
    assert m["targets"] == targets and m["detected"] >= floor_detected
    assert m["false_per_window"] <= ceiling_false


def test_evaluate_finds_truth_txt_beside_a_folder_of_frames(tmp_path, cli):
    from irdetect.simulate import simulate

    frames, truth = simulate("wan2008", snr=5, rng=4, n_frames=36, height=64, width=64,
                             n_targets=1, directions=(0.0,))
    seq = tmp_path / "seq"
    (seq / "frames").mkdir(parents=True)
    for i, f in enumerate(np.clip(frames, 0, 255).astype(np.uint8)):
        cv2.imwrite(str(seq / "frames" / f"{i + 1:04d}.png"), f)
    with open(seq / "truth.txt", "w") as fh:
        for r in truth:
            fh.write(f"{r['x']:.2f} {r['y']:.2f}\n")
    code, _, err = cli("process", seq / "frames", "-o", tmp_path / "r.h5")
    assert code == 0, err
    code, out, err = cli("evaluate", tmp_path / "r.h5", "--json")          # input's folder
    assert code == 0, err
    code2, out2, _ = cli("evaluate", tmp_path / "r.h5", "--truth", seq, "--json")
    assert code2 == 0 and out2 == out
    import json
    assert json.loads(out)["detection"]["targets"] == 3
    code, _, err = cli("evaluate", tmp_path / "r.h5", "--truth", tmp_path / "seq" / "frames"
                       / "..", "--json")
    assert code == 0
    (seq / "truth.txt").unlink()
    code, _, err = cli("evaluate", tmp_path / "r.h5", "--truth", seq / "frames")
    assert code == 2 and "truth.txt" in err


def test_local_significance_discounts_clutter_correlated_in_time():
    # the verification's statistic assumes independent frames; a clutter residue that
    # stays put (registration residue of textured ground) scores as high as a target.
    # The local test measures the track against parallel tracks around it.
    from irdetect.verify import Evidence, local_significance, track_significance

    rng = np.random.default_rng(3)
    n, h, w = 36, 64, 96
    frames = rng.normal(0, 1, (n, h, w)).astype(np.float32)
    texture = cv2.GaussianBlur(rng.normal(0, 1, (h, 48)).astype(np.float32), (0, 0), 1.0)
    frames[:, :, 48:] += 3.0 * texture / texture.std()       # the same in every frame
    yy, xx = np.mgrid[:h, :w]
    t = np.arange(n)
    for i in t:                                              # a target in the quiet half
        x, y = 10 + 0.5 * i, 30.0
        frames[i] += 2.0 * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * 0.8 ** 2))
    ev = Evidence(frames=frames, index=t, times=(11.0, 23.0, 35.0), report=(5.5, 17.5, 29.5),
                  sigma=1.0)
    # the target's chain, and a chain on a texture point 2 sd above its mean (the residue
    # stays put in the image)
    inner = texture[8:-8, 8:-8] / texture.std()
    ty, tx = np.unravel_index(np.argmin(np.abs(inner - 2.0)), inner.shape)
    cx, cy = 48 + 8 + tx, 8 + ty
    points = np.array([[[10 + 0.5 * 11, 30], [10 + 0.5 * 23, 30], [10 + 0.5 * 35, 30]],
                       [[cx, cy]] * 3], float)
    z, c, v = track_significance(ev, points)
    local = local_significance(ev, c, v, z)
    assert z[0] > 6.5 and z[1] > 6.5                 # both pass the verification
    assert local[0] > 4.0 > local[1]                 # only the target passes the local test
    # in white noise the local test is no stricter than the verification
    assert local[0] >= 0.8 * z[0]


def test_local_test_spread_is_the_upper_one():
    # a target the camera holds still leaves its own trail in the registered background:
    # the parallel tracks on that side sum low (a long lower tail). The local test's
    # spread is the upper one, which that tail does not widen (daub-data22-a window 0).
    from irdetect.robust import median_mad_sigma, upper_sigma
    from irdetect.verify import Evidence, local_significance, local_sums, track_significance

    rng = np.random.default_rng(5)
    g = rng.normal(0, 1, (200, 64))
    med, up = upper_sigma(g)
    assert np.allclose(med, np.median(g, axis=1)) and 0.8 < up.mean() < 1.2
    sunk = g.copy()                              # 40 % of the samples pulled down
    sunk[:, :26] -= np.abs(rng.normal(0, 6, (200, 26)))
    assert upper_sigma(sunk)[1].mean() < 1.5 < median_mad_sigma(sunk)[1].mean()

    n, h, w = 36, 64, 64
    frames = np.random.default_rng(5).normal(0, 1, (n, h, w)).astype(np.float32)
    yy, xx = np.mgrid[:h, :w]
    r2 = (xx - 32.0) ** 2 + (yy - 32.0) ** 2
    cos = (xx - 32.0) / np.sqrt(np.maximum(r2, 1e-9))
    # the trail: beyond 4 px, sunk by up to 2 sigma per frame, the most behind the target
    frames -= (2.0 * ((1 - cos) / 2) ** 3 * (r2 > 16)).astype(np.float32)
    frames += 1.1 * np.exp(-r2 / (2 * 0.8 ** 2))
    ev = Evidence(frames=frames, index=np.arange(n), times=(11.0, 23.0, 35.0),
                  report=(5.5, 17.5, 29.5), sigma=1.0)
    z, c, v = track_significance(ev, np.array([[[32.0, 32.0]] * 3]))
    local = local_significance(ev, c, v, z)
    assert 6.5 < z[0] < 8                        # passes the verification (6.5)
    assert local[0] >= 5.0                       # and the default local test (3.5)
    # the MAD of both sides would have dropped it
    m2, s2 = median_mad_sigma(local_sums(ev, c, v))
    assert (z[0] - m2[0]) / max(s2[0], 1.0) < 3.3


@pytest.mark.parametrize("name", ["istd640-seq1-101", "istd640-seq2-204", "istd640-seq4-71"])
def test_a_fast_target_that_turns_gets_one_right_track(name):
    # 2-4 px/frame targets whose 4-5 detections curve (seq4-71 under a 4.6 px/frame pan):
    # no track without the vote band, and a false one from the pieces of the target's
    # streak in the combined frames or a second piece of its path (issue 26)
    from conftest import real_sequence
    from irdetect import tables
    from irdetect.io import open_sequence, read_point_annotations
    from irdetect.metrics.initiation import score_track_paths

    folder = real_sequence(name)
    with open_sequence(folder / "frames") as src:
        frames = src[:]
    truth = read_point_annotations(folder / "truth.txt", len(frames))
    out = detect_sequence(frames, ProcessConfig())
    f, x, y = truth["frame"], truth["x"], truth["y"]
    target = truth["target"]
    if name == "istd640-seq2-204":
        # a second small point crosses the sky, 2.6 px/frame from (158, 237) over frames
        # 0-35 (seen by eye; truth.txt names one target): its track is not false
        k = np.arange(36)
        f, target = np.r_[f, k], np.r_[target, np.full(36, 1)]
        x, y = np.r_[x, 158.6 - 1.61 * k], np.r_[y, 237.0 + 2.01 * k]
    rows = tables.from_columns(tables.TRUTH, frame=f, target=target, x=x, y=y)
    s = score_track_paths(out["tracks"], rows, gate=10.0, camera=out.get("camera"))
    assert s["n_false"] == 0 and s["pt"][0] == 1.0
    assert s["n_tracks"] == len(np.unique(target))                # one track per object
