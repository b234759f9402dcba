"""The combined-frame path's operating point: a CFAR on the integrated map of the frames a
chain spans (irdetect.operating, irdetect.pipeline)."""

import cv2
import numpy as np
import pytest

from irdetect import tables
from irdetect.operating import MAXIMUM_PX, integrated_map, map_threshold, significance
from irdetect.pipeline.fusion import dilated_sum


def _matched_noise(rng, n=12, shape=(240, 320)):
    f = rng.normal(size=(n, *shape)).astype(np.float32)
    f = np.stack([cv2.GaussianBlur(x, (0, 0), 0.6) for x in f])
    return f / f.std()


def _maxima_at_or_above(z, level):
    peak = (z >= cv2.dilate(z, np.ones((MAXIMUM_PX, MAXIMUM_PX), np.uint8))) & (z > 0)
    return int((z[peak] >= level).sum())


def test_map_level_on_noise_only_windows_holds_the_stated_rate():
    # 20 windows of white noise: the maxima at or above the level per window are at most
    # the stated rate x 12 frames and not far below it (an exponential tail fitted to a
    # Gaussian one extrapolates high: 0.55 of 1.2 measured)
    rng = np.random.default_rng(0)
    counts = []
    for _ in range(20):
        z = integrated_map(dilated_sum(_matched_noise(rng)) / 12)[0]
        counts.append(_maxima_at_or_above(z, map_threshold(z, 0.1, 12)))
    assert 0.25 * 1.2 <= np.mean(counts) <= 1.2


def test_a_windows_level_allows_the_rate_over_its_own_frames(monkeypatch):
    # a window's detections are judged on its map of the 36 frames its chains span, and a
    # structure that persists is a false detection in each of the 3 windows whose maps
    # hold it: a map's level allows rate x 12 maxima (the window's frames), not rate x 36
    from irdetect.pipeline import combined, detect_sequence
    from irdetect.simulate import simulate

    frames, _ = simulate("wan2008", snr=4.0, rng=1)
    lengths = []

    def recorded(z, rate, length):
        lengths.append(length)
        return map_threshold(z, rate, length)

    monkeypatch.setattr(combined, "map_threshold", recorded)
    out = detect_sequence(frames)
    assert len(out["detections"]) >= 4 and lengths and set(lengths) == {12}


def test_integrated_map_measures_persistent_clutter_not_white_noise_scaling():
    # the same residue in all 12 frames (clutter that persists) keeps one frame's scale;
    # independent frames give sigma / sqrt(12)
    rng = np.random.default_rng(1)
    white = _matched_noise(rng)
    still = np.repeat(white[:1], 12, axis=0)
    _, _, s_white = integrated_map(white.mean(axis=0))
    _, _, s_still = integrated_map(still.mean(axis=0))
    assert np.median(s_still) == pytest.approx(np.median(s_white) * np.sqrt(12), rel=0.25)
    # a point of 1.5 frame sigmas in every frame: significant in white noise, not in
    # persistent residue of its own size
    for frames, expect in ((white, True), (still, False)):
        f = frames.copy()
        f[:, 100, 150] += 1.5
        z = integrated_map(f.mean(axis=0))
        sig = significance(z, np.array([f[:, 100, 150].mean()]), np.array([150.0]),
                           np.array([100.0]))[0]
        assert bool(sig >= map_threshold(z[0], 0.1, 12)) is expect


def test_map_threshold_refuses_bad_rates_and_measures_nothing_on_tiny_maps():
    with pytest.raises(ValueError, match="rate"):
        map_threshold(np.zeros((64, 64), np.float32), 0.0, 12)
    assert map_threshold(np.zeros((8, 8), np.float32), 0.1, 12) == -np.inf


def test_finish_keeps_the_combined_detections_that_reach_their_level():
    from irdetect.config import FrameConfig, ProcessConfig
    from irdetect.pipeline import finish

    det = tables.from_columns(
        tables.DETECTION, x=[20.0, 40.0, 60.0], y=[20.0, 40.0, 60.0], vx=[0.0] * 3,
        vy=[0.0] * 3, frame_start=[0] * 3, frame_end=[11] * 3, combined_frame=[0] * 3,
        path=[1] * 3, significance=[6.0, 4.0, 1.0], level=[5.0, 5.0, -np.inf])
    config = ProcessConfig(frame=FrameConfig(enabled=False))
    out = finish(det, tables.empty(tables.FRAME_DETECTION),
                 tables.from_columns(tables.CAMERA, frame=np.arange(36), dx=np.zeros(36),
                                     dy=np.zeros(36)),
                 config, n_frames=36, shape=(80, 80))
    assert out["detections"]["x"].tolist() == [20.0, 60.0]


def test_dim_targets_keep_every_window_the_verification_confirmed():
    # the level is measured on the 36 frames a chain spans, as the verification sums
    # them: on white noise it drops no target the verification keeps (with 12 frames it
    # dropped 3 % of the SNR 2 target-windows of wan2008)
    from irdetect.config import OperatingConfig, ProcessConfig
    from irdetect.pipeline import detect_sequence
    from irdetect.simulate import simulate

    frames, _ = simulate("wan2008", snr=2.0, rng=3)
    on = detect_sequence(frames)
    off = detect_sequence(frames, ProcessConfig(operating=OperatingConfig(false_rate=0.0)))
    assert len(off["detections"]) >= 10
    np.testing.assert_array_equal(on["detections"][["x", "y"]], off["detections"][["x", "y"]])
    assert np.all(on["detections"]["level"] > 3.5)


def test_registered_mean_adds_up_structure_at_rest_in_the_scene():
    from irdetect.pipeline.fusion import dilated_sum, registered_mean

    # a point at rest in the scene, the camera moving 3 px/frame along x: in frame t it
    # is at x = 20 + 3 t; the reference is frame 4's offset
    frames = np.zeros((8, 32, 64), np.float32)
    offsets = np.column_stack([3.0 * np.arange(8), np.zeros(8)])
    for t in range(8):
        frames[t, 10, 20 + 3 * t] = 1.0
    moved = registered_mean([(frames[:4], offsets[:4]), (frames[4:], offsets[4:])],
                            offsets[4])
    assert moved[10, 32] == pytest.approx(1.0)           # every frame's sample, in place
    assert (dilated_sum(frames) / 8).max() == pytest.approx(1 / 8)   # fixed in the image
    # a pixel that only some moved frames cover takes the mean of those (not of zeros)
    ones = registered_mean([(np.ones_like(frames), offsets)], offsets[4])
    assert np.allclose(ones, 1.0)
