"""The harbour scene reproduces the paper's events, and its ships pass the paper's gates."""

import numpy as np
import pytest

from irdetect.errors import InputError
from irdetect.simulate.harbour import harbour_truth, load_harbour, ship_paths, simulate_harbour
from irdetect.track import extract_regions


def test_preset_events():
    s = load_harbour()
    assert (s.width, s.height, s.frame_rate, s.n_frames >= 900) == (320, 240, 25.0, True)
    truth = harbour_truth(s)
    by = {j: truth[truth["target"] == j] for j in range(4)}
    for j in (0, 1):                                   # T1, T2 moored
        assert np.ptp(by[j]["x"]) == 0 and len(by[j]) == s.n_frames
    t3 = by[2]                                         # slow, right to left
    assert np.all(np.diff(t3["x"]) < 0) and -0.5 < np.diff(t3["x"]).mean() < 0
    t4 = by[3]                                         # fast, left to right, from frame 162
    assert np.diff(t4["x"]).mean() > 1 and t4["x"][-1] > s.width - 3
    paths = ship_paths(s)
    x162 = paths[3, 0] + paths[3, 2] * 162             # centre still outside, bow inside
    assert x162 < 0 < x162 + s.ships[3].length / 2
    assert paths[3, 0] + paths[3, 2] * 161 + s.ships[3].length / 2 < 0
    # T3's hull reaches T2's at the merge frame (2.5 px gap left for the soft edges)
    t2, t3s = s.ships[1], s.ships[2]
    gap = paths[2, 0] + paths[2, 2] * s.merge_frame - paths[1, 0]
    assert gap == pytest.approx((t2.length + t3s.length) / 2 + 2.5)
    assert all(5 <= np.pi * sh.length * sh.height / 4 <= 30 and 100 <= sh.grey <= 180
               for sh in s.ships)


def test_frames_and_ship_regions():
    frames, truth = simulate_harbour(n_frames=4, rng=1)
    again, _ = simulate_harbour(n_frames=4, rng=1)
    assert frames.shape == (4, 240, 320) and frames.dtype == np.uint8
    np.testing.assert_array_equal(frames, again)
    regions = extract_regions(frames[2])               # the paper's gates: g 100-180, s 5-30
    t = truth[truth["frame"] == 2]
    assert len(t) == 3
    for row in t:
        d = np.hypot(regions["x"] - row["x"], regions["y"] - row["y"])
        assert d.min() < 1.0


def test_bad_preset():
    with pytest.raises(InputError, match="unknown harbour scenario"):
        load_harbour("nope")
    with pytest.raises(InputError, match="not a harbour"):
        load_harbour("wan2008")
