import math

import numpy as np
import pytest

from irdetect.hough import (fuzzy_hough_transform, hough_grid, hough_transform, nms_peaks,
                            parallel_combine, rho_sigma)


def _on_line(rho, theta, s):
    """Points (x, y) at signed distances s along the line rho = x cos(theta) + y sin(theta)."""
    return rho * math.cos(theta) - s * math.sin(theta), rho * math.sin(theta) + s * math.cos(theta)


def test_cell_centres_follow_the_paper():
    g = hough_grid(rho_max=10, n_rho=4, n_theta=4)
    assert np.allclose(g.theta_centres, (np.arange(4) + 0.5) * math.pi / 4)
    assert np.allclose(g.rho_centres, [-7.5, -2.5, 2.5, 7.5])


def test_line_peaks_at_its_cell():
    g = hough_grid(rho_max=100, rho_step=1.0, n_theta=180)
    theta, rho = g.theta_centres[60], 30.2
    x, y = _on_line(rho, theta, np.linspace(-40, 40, 15))
    acc = hough_transform(x, y, grid=g)[0]
    j, n = np.unravel_index(np.argmax(acc), acc.shape)
    assert acc.max() == 15 and n == 60 and abs(g.rho_centres[j] - rho) <= 0.5


def test_fuzzy_noiseless_line_peaks_at_right_cell_and_range_zero_is_safe():
    g = hough_grid(rho_max=100, rho_step=1.0, n_theta=90)
    theta, rho = g.theta_centres[20], 40.0
    x, y = _on_line(rho, theta, np.linspace(-30, 30, 5))
    sr = rho_sigma(g.theta_centres, x=x, y=y, sigma_range=1.0, sigma_azimuth=0.01)
    acc = fuzzy_hough_transform(x, y, grid=g, sigma_rho=sr)[0]
    j, n = np.unravel_index(np.argmax(acc), acc.shape)
    assert n == 20 and abs(g.rho_centres[j] - rho) <= 0.5
    # a measurement at the radar: range 0, the azimuth term vanishes; no NaN, the spread
    # is floored at half a cell (rho = 0 lies on a cell edge: exp(-1/2) in both cells)
    sr0 = rho_sigma(g.theta_centres, x=np.zeros(1), y=np.zeros(1), sigma_range=0.0,
                    sigma_azimuth=0.01, range_=np.zeros(1), azimuth=np.zeros(1))
    a0 = fuzzy_hough_transform([0.0], [0.0], grid=g, sigma_rho=sr0)
    assert np.isfinite(a0).all() and a0.max() == pytest.approx(math.exp(-0.5))


def test_parallel_rule_removes_single_scan_cell():
    per_scan = np.zeros((3, 4, 4))
    per_scan[:, 1, 1] = 1.0          # supported by every scan
    per_scan[0, 2, 2] = 5.0          # one scan only, however strong
    b = parallel_combine(per_scan)
    assert b[1, 1] == 3 and b[2, 2] == 0
    assert parallel_combine(per_scan, q1=1.0)[1, 1] == 0


def test_absurd_resolution_is_refused_with_the_reason():
    with pytest.raises(ValueError, match="limit"):
        hough_grid(rho_max=1e6, rho_step=1e-3, n_theta=1000)
    with pytest.raises(ValueError, match="rho_step"):
        hough_grid(rho_max=10, rho_step=0.0)


def test_nan_points_rejected():
    g = hough_grid(rho_max=10, n_rho=10, n_theta=10)
    with pytest.raises(ValueError, match="NaN"):
        hough_transform([np.nan], [1.0], grid=g)


def test_nms_keeps_one_per_peak():
    acc = np.zeros((20, 20))
    acc[5, 5], acc[5, 6], acc[6, 5] = 9, 8, 7
    acc[15, 12] = 6
    pk = nms_peaks(acc, size=3, threshold=5)
    assert pk.tolist() == [[5, 5], [15, 12]]


def _greedy_nms(acc, size, threshold):
    """Reference: one peak at a time, theta wrapping with rho mirrored."""
    a = np.array(acc, float)
    n_rho, n_theta = a.shape
    flat = np.flatnonzero(a > threshold)
    order = flat[np.argsort(-a.ravel()[flat], kind="stable")]
    alive = np.zeros(a.size, bool)
    alive[order] = True
    h, out = size // 2, []
    for idx in order:
        if not alive[idx]:
            continue
        j, n = divmod(int(idx), n_theta)
        out.append((j, n))
        rows = np.arange(j - h, j + h + 1)
        for col in range(n - h, n + h + 1):
            r = (n_rho - 1 - rows) if (col < 0 or col >= n_theta) else rows
            r = r[(r >= 0) & (r < n_rho)]
            alive[r * n_theta + col % n_theta] = False
    return np.array(out, np.int64).reshape(-1, 2)


def test_parallel_nms_is_exactly_greedy_with_wrap_and_tiles():
    rng = np.random.default_rng(2)
    for _ in range(40):
        n_rho, n_theta = rng.integers(3, 25, 2)
        size = int(rng.choice([1, 3, 5]))
        accs = rng.integers(0, 6, (3, n_rho, n_theta)).astype(float)
        assert np.array_equal(nms_peaks(accs[0], size=size, threshold=2.5),
                              _greedy_nms(accs[0], size, 2.5))
        tiled = nms_peaks(accs, size=size, threshold=2.5)
        for g in range(3):
            assert np.array_equal(tiled[tiled[:, 0] == g][:, 1:], _greedy_nms(accs[g], size, 2.5))


def test_a_vote_band_joins_points_astride_a_cell_edge_and_counts_each_once():
    # three points of one line, two of them 0.3 px either side of the rho-cell edge at
    # rho 10: no cell holds more than two votes without a band, one holds three with it
    g = hough_grid(rho_max=40, rho_step=2.0, n_theta=8)
    k = 3
    xs, ys = zip(*(_on_line(r, g.theta_centres[k], s)
                   for r, s in ((9.7, -20.0), (10.3, 0.0), (9.8, 20.0))))
    x, y = np.array(xs), np.array(ys)
    assert hough_transform(x, y, grid=g)[0][:, k].max() == 2
    assert hough_transform(x, y, grid=g, band=1.0)[0][:, k].max() == 3
    # a band over several cells adds one vote per point to each, never two
    wide = hough_transform(x, y, grid=g, band=5.0)[0]
    assert wide.max() == 3 and wide[:, k].sum() == 3 * 6
    with pytest.raises(ValueError, match="band"):
        hough_transform(x, y, grid=g, band=-1.0)
