"""Directional detection: a streak of known direction is found in that direction."""

import numpy as np
import pytest

from irdetect.detect import DIRECTION_DEGREES, detect, direction_degrees, line_kernels


def _streak(angle_deg, amp=2.0, seed=0, size=64):
    rng = np.random.default_rng(seed)
    img = rng.normal(0, 1, (size, size)).astype(np.float32)
    a = np.deg2rad(angle_deg)
    for s in np.arange(-8, 9):                # 17 px streak through the centre
        x, y = 32 + s * np.cos(a), 32 + s * np.sin(a)
        img[int(round(y)), int(round(x))] += amp
    return img


@pytest.mark.parametrize("index", range(4))
@pytest.mark.parametrize("seed", [0, 1])
def test_streak_is_found_in_its_direction(index, seed):
    det = detect(_streak(DIRECTION_DEGREES[index], seed=seed), window=7, k=4.0)
    assert det.mask[32, 32]
    assert det.direction[32, 32] == index
    assert det.response[32, 32] > 4.0
    assert det.count < 60                      # the streak, not the noise


def test_more_directions_follow_an_off_axis_streak():
    img = _streak(22.5, amp=1.6, seed=3)
    four = detect(img, window=11, k=4.0, sigma="global")
    eight = detect(img, window=11, k=4.0, sigma="global", directions=8)
    assert direction_degrees(8)[eight.direction[32, 32]] == 22.5
    assert eight.response[32, 32] > four.response[32, 32]
    for kern in line_kernels(11, 8):
        assert kern.sum() == pytest.approx(11.0)


def test_cfar_false_alarm_rate_on_noise():
    rng = np.random.default_rng(4)
    img = rng.normal(100, 7, (256, 256)).astype(np.float32)
    det = detect(img, window=5, k=4.0)
    # 4 directions x 65536 px x P(z > 4) = 4 x 65536 x 3.2e-5 ~ 8; allow slack
    assert det.count < 40
    det_hi = detect(img * 10, window=5, k=4.0)            # scale-free: same pixels
    assert np.array_equal(det.mask, det_hi.mask)


@pytest.mark.parametrize("img", [np.zeros((40, 40)), np.full((40, 40), 9.0),
                                 np.full((40, 40), np.nan)])
def test_flat_or_nan_frames_give_no_candidates(img):
    det = detect(img)
    assert det.count == 0 and np.isfinite(det.response).all()
    assert (det.direction == -1).all()


def test_single_hot_pixel_is_one_small_candidate():
    img = np.zeros((40, 40), np.float32)
    img[20, 20] = 50.0
    det = detect(img, window=3)
    assert det.mask[20, 20] and det.count <= 9


@pytest.mark.parametrize("kwargs, name", [
    ({"window": 4}, "window"), ({"k": 0}, "k"), ({"sigma": "median"}, "sigma"),
    ({"tile": 2}, "tile"), ({"smooth": -1.0}, "smooth"), ({"directions": 1}, "directions")])
def test_bad_parameters_are_named(kwargs, name):
    with pytest.raises(ValueError, match=name):
        detect(np.zeros((16, 16)), **kwargs)
