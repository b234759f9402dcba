"""Combined frames: projections, windows, and the DP merit following a moving point."""

import numpy as np
import pytest

from irdetect.combine import combine, frames_needed, window_starts


def test_windows_and_projections():
    stack = np.zeros((30, 6, 6), np.float32)
    stack[3, 1, 1] = 4.0
    stack[14, 2, 2] = 6.0
    assert list(window_starts(30, length=12, step=12)) == [0, 12]   # partial window dropped
    assert list(window_starts(30, length=12, step=6)) == [0, 6, 12, 18]
    # the tail window covers the last frames the others leave, and only then
    assert list(window_starts(30, length=12, step=12, tail=True)) == [0, 12, 18]
    assert list(window_starts(36, length=12, step=12, tail=True)) == [0, 12, 24]
    assert list(window_starts(31, length=12, step=6, tail=True)) == [0, 6, 12, 18, 19]
    assert list(window_starts(11, length=12, step=12, tail=True)) == []
    assert frames_needed(3, length=12, step=12) == 36
    mx = combine(stack, projection="max", tail=False)
    assert mx.shape == (2, 6, 6) and mx[0, 1, 1] == 4.0 and mx[1, 2, 2] == 6.0
    stack[29, 3, 3] = 5.0                               # in the last frame
    mx = combine(stack, projection="max")
    assert mx.shape == (3, 6, 6) and mx[2, 2, 2] == 0.0 and mx[2, 3, 3] == 5.0
    assert combine(stack, projection="mean")[0, 1, 1] == pytest.approx(4.0 / 12)
    assert combine(stack, projection="sum", length=6, step=6)[2, 2, 2] == 6.0
    assert combine(stack[:5]).shape == (0, 6, 6)


def test_dp_merit_follows_a_moving_point_to_its_last_position():
    rng = np.random.default_rng(0)
    stack = rng.normal(0, 1, (12, 40, 40)).astype(np.float32)
    yy, xx = np.mgrid[0:40, 0:40]
    for t in range(12):                        # 1 px/frame down-right, SNR 3
        stack[t] += 3 * np.exp(-((xx - 10 - t) ** 2 + (yy - 12 - 0.5 * t) ** 2) / 0.72)
    merit = combine(stack, projection="dp", dp_decay=1.0)[0]
    peak = np.unravel_index(np.argmax(merit), merit.shape)
    assert abs(peak[1] - 21) <= 1 and abs(peak[0] - 17.5) <= 1.5
    # the paper's max projection of the same window gives a much weaker peak in sigmas
    def z(img, y, x):
        med = np.median(img)
        return (img[y, x] - med) / (1.4826 * np.median(np.abs(img - med)))
    mx = combine(stack, projection="max")[0]
    assert z(merit, *peak) > 2 * z(mx, 14, 14)


@pytest.mark.parametrize("kwargs, name", [
    ({"projection": "median"}, "projection"), ({"length": 0}, "length"), ({"step": 0}, "step"),
    ({"dp_radius": 0}, "dp_radius"), ({"dp_decay": 1.5}, "dp_decay"),
    ({"dp_smooth": -1.0}, "dp_smooth")])
def test_bad_parameters_are_named(kwargs, name):
    with pytest.raises(ValueError, match=name):
        combine(np.zeros((12, 4, 4)), **kwargs)
