"""The combined-frame path's operating point: a CFAR on each window's integrated map
(irdetect.operating) and its hysteresis (irdetect.pipeline.fusion.operating_point)."""

import cv2
import numpy as np
import pytest

from irdetect import tables
from irdetect.operating import MAXIMUM_PX, integrated_map, map_threshold, significance
from irdetect.pipeline.fusion import dilated, operating_point


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
        z = integrated_map(dilated(_matched_noise(rng)))[0]
        counts.append(_maxima_at_or_above(z, map_threshold(z, 0.1, 12)))
    assert 0.25 * 1.2 <= np.mean(counts) <= 1.2


def test_integrated_map_measures_persistent_clutter_not_white_noise_scaling():
    # the same residue in all 12 frames (clutter that persists) keeps one frame's scale;
    # independent frames give sigma / sqrt(12)
    rng = np.random.default_rng(1)
    white = _matched_noise(rng)
    still = np.repeat(white[:1], 12, axis=0)
    _, _, s_white = integrated_map(white)
    _, _, s_still = integrated_map(still)
    assert np.median(s_still) == pytest.approx(np.median(s_white) * np.sqrt(12), rel=0.25)
    # a point of 1.5 frame sigmas in every frame: significant in white noise, not in
    # persistent residue of its own size
    for frames, expect in ((white, True), (still, False)):
        f = frames.copy()
        f[:, 100, 150] += 1.5
        z = integrated_map(f)
        sig = significance(z, np.array([f[:, 100, 150].mean()]), np.array([150.0]),
                           np.array([100.0]))[0]
        assert bool(sig >= map_threshold(z[0], 0.1, 12)) is expect


def test_map_threshold_refuses_bad_rates_and_measures_nothing_on_tiny_maps():
    with pytest.raises(ValueError, match="rate"):
        map_threshold(np.zeros((64, 64), np.float32), 0.0, 12)
    assert map_threshold(np.zeros((8, 8), np.float32), 0.1, 12) == -np.inf


def _det(k, x, y, vx=0.0, sig=10.0, level=5.0):
    return tables.from_columns(tables.DETECTION, x=[x], y=[y], vx=[vx], vy=[0.0],
                               frame_start=[12 * k], frame_end=[12 * k + 11],
                               combined_frame=[k], significance=[sig], level=[level])


def test_operating_point_keeps_a_faint_window_of_a_track_and_drops_lone_clutter():
    det = np.concatenate([
        _det(0, 50.0, 50.0, vx=0.1),              # strong
        _det(1, 51.2, 50.0, vx=0.1, sig=3.0),     # faint, on the strong one's track
        _det(3, 50.4, 50.0, vx=0.1, sig=3.0),     # faint, 3 windows on: beyond REACH
        _det(1, 90.0, 20.0, sig=4.9),             # faint, alone
        _det(2, 70.0, 70.0, sig=3.0, level=-np.inf),   # no operating point: kept
    ])
    assert operating_point(det, 3.0).tolist() == [True, True, False, False, True]
