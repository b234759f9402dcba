"""Clutter suppression: each suppressor removes the clutter it is built for and keeps a point."""

import cv2
import numpy as np
import pytest

from irdetect.suppress import (BRIGHT_MIN, METHODS, _fixed_pattern, _median_axis0, noise_sigma,
                               prefer_registered, residue, suppress)


def _point(frame, x, y, amp):
    yy, xx = np.mgrid[0:frame.shape[0], 0:frame.shape[1]]
    frame += amp * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * 0.6 ** 2))
    return frame


def _edge_scene(tilt=0.0):
    frame = np.full((64, 64), 50.0, np.float32)
    yy, xx = np.mgrid[0:64, 0:64]
    frame[yy > 40 + tilt * xx] += 80.0          # bright edge (a horizon)
    return _point(frame, 20.0, 15.0, 20.0)


@pytest.mark.parametrize("method, tilt", [("tophat", 0.0), ("tophat", 0.2), ("maxmean", 0.0),
                                          ("maxmedian", 0.0)])
def test_spatial_suppressors_remove_an_edge_and_keep_a_point(method, tilt):
    # the directional filters predict edges along their 4 directions (a 0.2 slope edge
    # leaves residue with them: measured in docs/results/detection.md on clutter scenes)
    res = suppress(_edge_scene(tilt), method=method, size=9)
    assert res.dtype == np.float32 and res.shape == (64, 64)
    assert res[15, 20] > 12.0                  # the point keeps most of its 20 grey levels
    # the edge (80 grey levels) leaves no bright residue: nothing away from the point
    # comes close to it (the directional ones leave a dark, negative rim, harmless for
    # detecting bright targets)
    far = np.ones_like(res, bool)
    far[10:21, 15:26] = False
    assert res[far].max() < 0.5 * res[15, 20]


def test_temporal_removes_still_clutter_keeps_a_moving_point():
    rng = np.random.default_rng(0)
    scene = _edge_scene() - _point(np.zeros((64, 64), np.float32), 20.0, 15.0, 20.0)
    stack = np.repeat(scene[None], 24, axis=0) + rng.normal(0, 1, (24, 64, 64)).astype(np.float32)
    for t in range(24):
        _point(stack[t], 10.0 + t, 30.0, 15.0)
    res = suppress(stack, method="temporal", history=12)
    assert res[20, 30, 30] > 10.0
    assert np.abs(res[20, 45:, :]).max() < 6.0     # the edge is gone (noise only)


def test_long_memory_keeps_a_point_that_stopped_and_nothing_that_was_there_before():
    # a point that stopped before the past frames is learnt by the 12-frame mean; the
    # median of older frames of a still camera (long_past) does not hold it. A point
    # that was in those older frames too, and a wide patch that arrived with it, stay
    # suppressed
    rng = np.random.default_rng(3)
    stack = rng.normal(50, 1, (36, 64, 64)).astype(np.float32)
    older = rng.normal(50, 1, (6, 64, 64)).astype(np.float32)
    for frame in stack:
        _point(frame, 20.0, 30.0, 12.0)           # arrived: not in `older`
        _point(frame, 45.0, 15.0, 12.0)           # was there before: in `older` too
        frame[40:60, 35:60] += 12.0               # a wide change (a cloud, a gain step)
    for frame in older:
        _point(frame, 45.0, 15.0, 12.0)
    past, block = stack[:24], stack[24:]
    plain = suppress(block, previous=past, method="temporal", history=12)
    kept = suppress(block, previous=past, long_past=older, method="temporal", history=12)
    assert np.abs(plain[:, 30, 20]).max() < 5.0
    assert kept[:, 30, 20].min() > 9.0
    assert np.abs(kept[:, 15, 45]).max() < 5.0
    assert np.abs(kept[:, 42:58, 37:58]).max() < 6.0
    np.testing.assert_array_equal(kept[:, :, :10], plain[:, :, :10])   # noise untouched
    few = suppress(block, previous=past, long_past=older[:3], method="temporal", history=12)
    np.testing.assert_array_equal(few, plain)  # fewer than HOLD_MIN: no long memory


def test_temporal_streams_like_one_block():
    rng = np.random.default_rng(1)
    stack = rng.normal(10, 2, (30, 16, 16)).astype(np.float32)
    whole = suppress(stack, method="temporal", history=5)
    second = suppress(stack[12:], previous=stack[:12], method="temporal", history=5)
    np.testing.assert_allclose(second, whole[12:], atol=1e-4)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.float32, np.int16, np.int32,
                                   np.float64])
def test_temporal_background_is_the_mean_of_the_past_frames(dtype):
    # the running sum takes uint8 / uint16 / float32 by cv2.accumulate, others by numpy:
    # every stored dtype gives the frame minus the mean of its `history` past frames
    rng = np.random.default_rng(6)
    raw = rng.integers(0, 250, (20, 9, 11)).astype(dtype)
    res = suppress(raw[8:], previous=raw[:8], method="temporal", history=5)
    f = raw.astype(np.float64)
    want = np.stack([f[t] - f[t - 5:t].mean(axis=0) for t in range(8, 20)])
    np.testing.assert_allclose(res, want, atol=1e-3)


def test_noise_sigma_is_robust():
    rng = np.random.default_rng(2)
    r = rng.normal(0, 3.0, (200, 200)).astype(np.float32)
    r[::10, ::10] += 200.0                     # 1 % bright outliers
    assert noise_sigma(r) == pytest.approx(3.0, rel=0.05)
    sig = noise_sigma(r, tile=50)
    assert sig.shape == (200, 200) and np.allclose(sig, 3.0, rtol=0.15)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("kind", ["zero", "constant", "nan", "hot"])
def test_degenerate_frames(method, kind):
    stack = np.zeros((4, 20, 20), np.float32)
    if kind == "constant":
        stack += 7.0
    elif kind == "nan":
        stack[1] = np.nan
        stack[2, 3:5, 3:5] = np.nan
    elif kind == "hot":
        stack[2, 10, 10] = 100.0
    res = suppress(stack, method=method, size=5)
    assert np.isfinite(res).all()
    if kind == "hot":
        assert res[2, 10, 10] > 50.0
    elif method != "none":
        assert np.abs(res).max() < 1e-4
    assert noise_sigma(res[0]) > 0


def test_registered_cleans_the_past_it_is_given_and_leaves_it_untouched():
    # the past frames go straight into the registered background's float32 stack: their
    # non-finite pixels take their frame's median there, as the window's own frames do,
    # and the caller's array is not written
    rng = np.random.default_rng(4)
    frames = rng.normal(100, 5, (30, 32, 40)).astype(np.float64)
    past, stack = frames[:19].copy(), frames[19:]
    past[3, 5:9, 7:12] = np.nan
    past[10, 0, 0] = np.inf
    given = past.copy()
    cleaned = past.copy()
    for f in cleaned:
        f[~np.isfinite(f)] = np.median(f[np.isfinite(f)])
    camera = np.column_stack([np.linspace(0, 6, 30), np.zeros(30)])
    res = suppress(stack, previous=past, camera=camera, method="registered")
    ref = suppress(stack, previous=cleaned, camera=camera, method="registered")
    assert np.isfinite(res).all() and np.array_equal(res, ref)
    assert np.array_equal(past, given, equal_nan=True)


@pytest.mark.parametrize("kwargs, name", [
    ({"method": "gauss"}, "method"), ({"size": 4}, "size"), ({"size": 1}, "size"),
    ({"guard": 4, "size": 9}, "guard"), ({"history": 0}, "history")])
def test_bad_parameters_are_named(kwargs, name):
    with pytest.raises(ValueError, match=name):
        suppress(np.zeros((8, 8)), **kwargs)


@pytest.mark.parametrize("t, h", [(31, 40), (44, 16), (3, 17), (12, 1)])
def test_fixed_pattern_and_time_median_equal_numpy(t, h):
    # banded (16 rows) and sorted in place, for speed and memory: the same values as
    # np.median of the whole frames' 3x3 high-pass; heights of part of a band, one, one and
    # a part, and 2.5 bands; odd and even counts; ties
    rng = np.random.default_rng(t)
    full = rng.normal(100.0, 5.0, (t, h, 23)).astype(np.float32)
    full[:, : h // 2] = np.round(full[:, : h // 2])
    ref = np.median(full, axis=0).astype(np.float32)
    assert np.array_equal(_median_axis0(full), ref)
    hp = np.stack([f - cv2.medianBlur(f, 3) for f in full])
    assert np.array_equal(_fixed_pattern(full), np.median(hp, axis=0).astype(np.float32))


def test_auto_sees_still_residue_under_noise():
    """A window that leaves faint residue in place (1.5 sigma on 1 % of the pixels, in
    every frame) is told from one that leaves none by the bright share of its mean
    residual, whatever the noise; counted on its frames the residue sinks into the noise
    and ``auto`` keeps the image-fixed background (docs/real.md, "With added noise")."""
    rng = np.random.default_rng(0)
    shape = (12, 128, 128)
    registered = rng.normal(0, 1, shape).astype(np.float32)
    temporal = rng.normal(0, 1, shape).astype(np.float32)
    spots = rng.random(shape[1:]) < 0.01
    temporal[:, spots] += 1.5
    assert residue(temporal, on_mean=True)[1] > 10 * BRIGHT_MIN
    assert residue(temporal, on_mean=False)[1] < BRIGHT_MIN
    assert residue(registered, on_mean=True)[1] < BRIGHT_MIN
    assert prefer_registered(registered, temporal)
    assert not prefer_registered(registered, temporal, on_mean=False)
