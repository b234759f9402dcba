"""Sea-sky line: found on the harbour scene within 2 px; none on a scene without horizon."""

import numpy as np
import pytest

from irdetect.simulate.harbour import load_harbour, simulate_harbour
from irdetect.track.seasky import find_sea_sky_line, line_rows, sea_sky_band


@pytest.mark.parametrize("tilt", [1.5, -3.0])
def test_found_on_harbour_within_2px(tilt):
    frames, _ = simulate_harbour(n_frames=3, horizon_tilt=tilt, rng=2)
    truth = load_harbour(horizon_tilt=tilt).horizon_line()
    w = frames.shape[2]
    for frame in frames:
        line = find_sea_sky_line(frame)
        assert line is not None and 0 <= line[1] < np.pi
        err = np.abs(line_rows(line, w) - line_rows(truth, w))
        assert err.max() < 2.0


def test_reversed_polarity_and_band():
    rng = np.random.default_rng(0)
    rows = np.arange(120)[:, None] + np.zeros((1, 160))
    frame = np.where(rows < 50 + 0.1 * np.arange(160), 40.0, 90.0) + rng.normal(0, 2, rows.shape)
    line = find_sea_sky_line(frame)
    assert np.abs(line_rows(line, 160) - (49.5 + 0.1 * np.arange(160))).max() < 1.0
    band = sea_sky_band(line, frame.shape, above=3, below=10)
    assert band[55, 0] and not band[40, 0] and not band[70, 0]
    assert sea_sky_band(None, frame.shape) is None


def test_no_horizon_gives_none_and_bad_input_is_named():
    flat = np.random.default_rng(1).normal(50, 2, (100, 100))
    assert find_sea_sky_line(flat) is None
    with pytest.raises(ValueError, match="smooth"):
        find_sea_sky_line(flat, smooth=0)
    with pytest.raises(ValueError, match="frame must be 2-D"):
        find_sea_sky_line(np.zeros(5))
