"""Repeated frames (a frame-rate conversion): irdetect.repeats and the tracker on them."""

import numpy as np
import pytest

from irdetect.repeats import PROBE, FrameGroups, NewFrames, frame_groups
from irdetect.simulate import simulate
from irdetect.track import track


def shown_twice(n: int, every: int = 5) -> np.ndarray:
    """Input frame -> source frame of a clip showing every ``every``-th frame twice."""
    return np.repeat(np.arange(n), np.where(np.arange(n) % every == every - 1, 2, 1))


def test_groups_map_new_frames_to_the_input_frames_showing_them():
    g = FrameGroups(8, [2, 3, 7])
    assert g.n_new == 5 and g.scale == pytest.approx(5 / 8)
    assert g.first(np.arange(5)).tolist() == [0, 1, 4, 5, 6]
    assert g.last(np.arange(5)).tolist() == [0, 3, 4, 5, 7]
    rows = np.zeros(2, [("frame", "<i8"), ("vx", "<f8"), ("vy", "<f8"), ("x", "<f8")])
    rows["frame"], rows["vx"], rows["x"] = [1, 4], [2.0, 4.0], [10.0, 20.0]
    out = g.expand(rows)
    assert out["frame"].tolist() == [1, 2, 3, 6, 7]
    assert out["x"].tolist() == [10, 10, 10, 20, 20]
    assert out["vx"] == pytest.approx([1.25] * 3 + [2.5] * 2)
    assert FrameGroups(4).expand(rows[:1])["vx"].tolist() == [2.0]    # no repeats: as given


def test_new_frames_view_and_the_probe():
    src = np.arange(200 * 4 * 5, dtype=np.uint16).reshape(200, 4, 5)
    idx = shown_twice(200)
    frames = src[idx]
    g = frame_groups(frames)
    # every repeat found, the ones after the probe's frames too
    assert g.n_new == 200 and len(idx) > PROBE
    view = NewFrames(frames, g)
    assert view.shape == src.shape and view.dtype == src.dtype
    np.testing.assert_array_equal(view[:], src)
    np.testing.assert_array_equal(view[37:121], src[37:121])
    np.testing.assert_array_equal(view[-1], src[-1])
    assert len(view[5:5]) == 0
    # a lone repeat (a recording's, now and then) is left alone
    lone = src[np.r_[0:40, 39, 40:200]]
    assert frame_groups(lone).n_new == len(lone)


def test_tracker_on_repeated_frames_tracks_the_new_frames():
    frames, truth = simulate("wan2008", snr=6, n_targets=1, n_frames=40, rng=1)
    idx = shown_twice(len(frames))
    plain, plain_tracks = track(frames)
    points, tracks = track(np.ascontiguousarray(frames[idx]))
    assert len(plain_tracks) == len(tracks) == 1
    # each input frame holds the point of the source frame it shows
    want = {int(f): p for f, p in zip(plain["frame"], plain)}
    assert len(points) == sum(int(f) in want for f in idx)
    for p in points:
        q = want[int(idx[p["frame"]])]
        assert (p["x"], p["y"]) == pytest.approx((q["x"], q["y"]))
        # velocities per input frame: 40 new frames in 48
        assert (p["vx"], p["vy"]) == pytest.approx((q["vx"] * 40 / 48, q["vy"] * 40 / 48))
    t, u = tracks[0], plain_tracks[0]
    assert t["frame_start"] == np.flatnonzero(idx == u["frame_start"])[0]
    assert t["frame_end"] == np.flatnonzero(idx == u["frame_end"])[-1]
    assert t["n_points"] == t["frame_end"] - t["frame_start"] + 1
    assert t["vx"] == pytest.approx(u["vx"] * 40 / 48)


def test_tracker_on_a_still_image_finds_nothing():
    frames = np.repeat(simulate("wan2008", snr=6, n_targets=1, n_frames=1, rng=2)[0], 30,
                       axis=0)
    assert frame_groups(frames).n_new == 1
    points, tracks = track(frames)
    assert len(points) == len(tracks) == 0
