"""The tracker's regions from the per-frame detector and its confirmation test (issue 28)."""

from types import SimpleNamespace

import numpy as np
import pytest

from irdetect.metrics.mot import clear_mot
from irdetect.operating import tail_share, tail_threshold
from irdetect.track import track
from irdetect.track.confirm import ClutterTest, still_chance
from irdetect.track.detector import peak_regions


def _blob(shape, x, y, sx, sy, amp):
    yy, xx = np.mgrid[:shape[0], :shape[1]]
    return amp * np.exp(-0.5 * (((xx - x) / sx) ** 2 + ((yy - y) / sy) ** 2))


def test_region_features_match_their_definitions():
    s = (_blob((60, 80), 20.3, 15.6, 1.5, 1.5, 12.0)
         + _blob((60, 80), 55.0, 40.0, 4.0, 1.0, 9.0)).astype(np.float32)
    r = peak_regions(s, 5.0)
    assert len(r) == 2
    for row, (x0, y0, top) in zip(r, [(20.3, 15.6, 12.0), (55.0, 40.0, 9.0)]):
        # the region: pixels connected to the peak at >= half its component's maximum
        sel = s >= 0.5 * s[int(round(y0)), int(round(x0))] * 0 + 0.5 * s.max(
            where=np.hypot(*np.mgrid[:60, :80][::-1] - np.array([x0, y0])[:, None, None])
            < 8, initial=0)
        sel &= np.hypot(*(np.mgrid[:60, :80][::-1] - np.array([x0, y0])[:, None, None])) < 12
        ys, xs = np.nonzero(sel)
        v = s[ys, xs].astype(float)
        assert row["area"] == sel.sum()
        assert row["grey"] == pytest.approx(v.mean(), rel=1e-5)
        assert row["contrast"] == pytest.approx(v.max(), rel=1e-5)
        assert row["x"] == pytest.approx((v * xs).sum() / v.sum(), abs=1e-6)
        assert row["y"] == pytest.approx((v * ys).sum() / v.sum(), abs=1e-6)
        assert (row["bx"], row["by"]) == (xs.min(), ys.min())
        assert (row["bw"], row["bh"]) == (np.ptp(xs) + 1, np.ptp(ys) + 1)
        c = np.cov(np.vstack([xs, ys]), aweights=v, bias=True)
        ev = np.linalg.eigvalsh(c)
        assert row["shape"] == pytest.approx(np.sqrt(ev[0] / ev[1]), rel=1e-6)
    assert r["shape"][0] > 0.9 and r["shape"][1] < 0.4      # round; elongated 4:1


def test_no_peak_no_region_and_bad_fraction_named():
    assert len(peak_regions(np.zeros((20, 20), np.float32), 5.0)) == 0
    with pytest.raises(ValueError, match="fraction"):
        peak_regions(np.zeros((20, 20), np.float32), 5.0, fraction=0.0)


def _clutter(rng, n=120, shape=(120, 160)):
    """Noise over a textured background with bright clutter blobs that stay put."""
    g = np.random.default_rng(rng)
    h, w = shape
    base = 200 + 30 * np.sin(np.arange(w) / 7.0)[None, :] + np.zeros((h, w))
    for _ in range(25):
        base += _blob(shape, g.uniform(5, w - 5), g.uniform(5, h - 5), g.uniform(0.8, 3),
                      g.uniform(0.8, 3), g.uniform(10, 60))
    return (base[None] + g.normal(0, 2.0, (n, h, w))).astype(np.float32)


@pytest.mark.parametrize("rng", [0, 1])
def test_clutter_only_sequence_gives_no_tracks(rng):
    points, tracks = track(_clutter(rng))
    assert len(tracks) == 0 and len(points) == 0


def test_panning_scene_one_track_in_image_coordinates():
    g = np.random.default_rng(3)
    import cv2
    scene = cv2.GaussianBlur(g.normal(0, 400, (400, 400)).astype(np.float32), (0, 0), 3) + 500
    n, h, w = 60, 120, 160
    frames = np.empty((n, h, w), np.float32)
    truth = np.zeros(n, [("frame", "<i8"), ("target", "<i8"), ("x", "<f8"), ("y", "<f8"),
                         ("amplitude", "<f8")])
    for t in range(n):
        ox, oy = 2 * t, t                      # the camera pans: the scene moves up-left
        frames[t] = scene[50 + oy:50 + oy + h, 60 + ox:60 + ox + w]
        # a target moving 0.8 px/frame right in the image
        x, y = 30 + 0.8 * t, 60.0
        frames[t] += _blob((h, w), x, y, 1.0, 1.0, 200.0)
        truth[t] = (t, 0, x, y, 60.0)
    frames += g.normal(0, 3, frames.shape).astype(np.float32)
    cams = []
    points, tracks = track(frames, camera_sink=cams.append)
    cam = np.concatenate(cams)
    assert len(cam) == n and cam["dx"][-1] == pytest.approx(-2 * (n - 1), abs=1.0)
    r = clear_mot(truth, points, gate=3.0)
    assert len(tracks) == 1 and r["mota"] > 0.9 and r["id_switches"] == 0
    # the track's velocity is against the scene: the target's 0.8 plus the pan's 2 px/frame
    assert tracks["vx"][0] == pytest.approx(0.8 + 2.0, abs=0.2)
    # in other units (a gain of 0.01 and an offset of 1000) the same track: every level is
    # measured from the data (4 real folders so converted, a scratch run: the same MOTA)
    other_points, other = track(frames * np.float32(0.01) + np.float32(1000.0))
    assert len(other) == 1
    np.testing.assert_allclose(other_points["x"], points["x"], atol=1e-3)
    np.testing.assert_allclose(other_points["y"], points["y"], atol=1e-3)


def _wide_blobs(rng, **over):
    """bench_tracking's blob seed 0 (wide PSF 2.6 px at SNR 4.1 over clouds of 5.6 noise
    sigmas, 4 targets at 0.5-2 px/frame), 48 frames of 320 x 240, and its truth."""
    from irdetect.simulate import simulate
    scene = dict(dtype="float32", noise_sigma=14.2, background=205.0, n_targets=4,
                 psf_sigma=2.6, snr=4.1, speed=[0.5, 2.0], directions=(), n_frames=48,
                 height=240, width=320, cloud_amplitude=80.0, cloud_scale=24.0, margin=12.0)
    scene.update(over)
    return simulate("wan2008", rng=rng, **scene)


def test_still_camera_dragged_by_its_targets_keeps_the_scene_still():
    # the camera's estimate follows the wide bright blobs (the static clouds do not pin it
    # down); auto's registered background is no better than the image-fixed one, so the
    # detector's scene coordinates must not follow it (they moved 0.4 px/frame with 4-px
    # jumps at keyframe changes: 11 tracks for 4 targets on 100 frames)
    from irdetect.camera import estimate_motion
    from irdetect.track.detector import detector_blocks
    frames, truth = _wide_blobs(0)
    raw = estimate_motion(frames)
    assert np.abs(raw).max() > 3.0            # the scene's own estimate is dragged
    scene = np.concatenate([off for _, _, off, _ in detector_blocks(frames)])
    assert scene.shape == (len(frames), 2) and np.abs(scene).max() < 1.0
    points, tracks = track(frames)
    r = clear_mot(truth, points, gate=5.2)
    assert len(tracks) == 4 and r["id_switches"] == 0 and r["mota"] > 0.95


def test_slow_wide_target_is_found_from_the_first_frames():
    # a 2.9-px blob at 0.5-2 px/frame: with only frames 0 .. t-1 as its image-fixed
    # background, frame t's blob all but cancelled (found from frame 7 on, bench_tracking
    # seed 65); the first window takes the frames after it as the start of its past
    frames, truth = _wide_blobs(65, dtype="uint8", noise_sigma=2.55, background=57.5,
                                n_targets=1, psf_sigma=2.9, snr=5.8, cloud_amplitude=0.0)
    points, tracks = track(frames)
    early = truth[truth["frame"] < 12]
    r = clear_mot(early, points[points["frame"] < 12], gate=5.8)
    assert len(tracks) == 1 and r["matches"] == len(early) and r["fp"] == 0


def _jumping(rng, n, jump_at):
    """A point target (PSF sigma 1 px, peak 30 over noise of sigma 3) at 0.8 px/frame that
    jumps 5 px at frame ``jump_at``; ``n`` frames of 96 x 128, and its truth."""
    g = np.random.default_rng(rng)
    h, w = 96, 128
    frames = g.normal(100, 3, (n, h, w)).astype(np.float32)
    truth = np.zeros(n, [("frame", "<i8"), ("target", "<i8"), ("x", "<f8"), ("y", "<f8"),
                         ("amplitude", "<f8")])
    for t in range(n):
        x, y = 20 + 0.8 * t + (5.0 if t >= jump_at else 0.0), 40 + 0.3 * t
        frames[t] += _blob((h, w), x, y, 1.0, 1.0, 30.0).astype(np.float32)
        truth[t] = (t, 0, x, y, 30.0)
    return frames, truth


def test_target_jumping_out_of_its_gate_keeps_its_id():
    # daub-data20: the target jumps 5 px in one frame (a camera jump its offsets miss); the
    # confirmed track coasts, a new one is confirmed where the target went and takes the
    # old one's id (it had ended with an id switch: IDF1 0.68)
    frames, truth = _jumping(4, 70, 35)
    points, tracks = track(frames)
    r = clear_mot(truth, points, gate=3.0)
    assert len(tracks) == 1 and r["id_switches"] == 0 and r["mota"] > 0.8
    assert len(np.unique(points["track_id"])) == 1


def test_a_target_restarted_while_tentative_keeps_its_first_hits():
    # easy3's shaking camera: the target jumps 5 px at frame 3, out of its tentative track's
    # gate; the track born there is confirmed and takes the lapsed one's hits of frames
    # 0-2 (it started at frame 3: 37 of 40 frames)
    frames, truth = _jumping(0, 40, 3)
    points, tracks = track(frames)
    r = clear_mot(truth, points, gate=3.0)
    assert len(tracks) == 1 and r["matches"] == len(frames) and r["fp"] == 0
    assert tracks["frame_start"][0] == 0 and tracks["n_points"][0] == len(frames)


@pytest.mark.parametrize("rng", [0, 1])
def test_a_line_is_no_track_a_point_beside_it_is(rng):
    # a bright bar (sigma 4 x 0.6 px) moving across itself, as an edge's residue moves
    # under a pan: its regions (shape ~0.3, short enough for the point test's 4-px ring)
    # are lines and start no track; the point target beside it keeps its track
    g = np.random.default_rng(rng)
    n, h, w = 60, 96, 128
    frames = g.normal(100, 2, (n, h, w)).astype(np.float32)
    for t in range(n):
        frames[t] += _blob((h, w), 40, 20 + 0.8 * t, 4.0, 0.6, 30.0).astype(np.float32)
        frames[t] += _blob((h, w), 30 + 0.6 * t, 70 - 0.3 * t, 1.0, 1.0, 30.0).astype(
            np.float32)
    tracks = track(frames)[1]
    assert len(tracks) == 1
    assert (tracks["x0"][0], tracks["y0"][0]) == (pytest.approx(30, abs=1),
                                                  pytest.approx(70, abs=1))
    assert len(track(frames, min_shape=0.0)[1]) == 2


def _clutter_sample(rng, n, score_scale, moved):
    """n clutter tracks' (score, displacement): scores 5 + an exponential tail."""
    return np.column_stack([5.0 + rng.exponential(score_scale, n), moved(n)])


def test_clear_mover_is_not_held_to_the_score_of_bright_static_clutter():
    rng = np.random.default_rng(3)
    # bright structure that stays put (displacements < 1 unit, scores up to ~50) sets a
    # high score level; a track moving 8 units meets only the clutter that moves as far
    test = ClutterTest((256, 256), false_tracks=0.001, score_floor=4.2, learn=0)
    sample = _clutter_sample(rng, 40, 10.0, lambda n: rng.uniform(0.0, 0.9, n))
    static_level = tail_threshold(sample[:, 0], 40, 0.001, 4.2)
    assert static_level > 30.0
    assert test.level(sample, 8.0, 40) < 10.0                 # the target's 30 passes
    assert test.level(sample, 0.5, 40) == pytest.approx(static_level)


def test_marginal_mover_meets_the_clutter_that_moves_as_far():
    rng = np.random.default_rng(4)
    # clutter that drifts (1-3 units) with scores ~5-8: a track of score 7 moving
    # 1.5 units is as good as that clutter and is not confirmed
    test = ClutterTest((256, 256), false_tracks=0.001, score_floor=4.2, learn=0)
    sample = _clutter_sample(rng, 40, 1.0, lambda n: rng.uniform(1.0, 3.0, n))
    track = SimpleNamespace(moved=1.5, still=0.0, E=0.0, score=7.0)
    assert test.level(sample, 1.5, 40) > 7.0
    assert not test.passes(track, sample, 40)
    assert test.passes(SimpleNamespace(moved=1.5, still=0.0, E=0.0, score=20.0), sample, 40)
    assert not test.passes(track, None, 40)                  # before ``learn`` frames


def test_a_fast_track_that_passes_the_motion_and_clutter_tests_is_no_clutter_sample():
    # tentative tracks of 20 hits that end unconfirmed, each measured by the test: a
    # straight one at 3 px/frame (a target that failed only the score level), one at 0.3
    # px/frame (a bright point drifting by parallax) and a point that stays put (clutter)
    test = ClutterTest((512, 640), false_tracks=0.001, floor=1e-6, window=30, learn=0)
    rng = np.random.default_rng(5)
    k = np.arange(20.0)

    def ended(vx, scatter, score):
        meas = np.column_stack([k, 100 + vx * k + rng.normal(0, scatter, 20),
                                200 + rng.normal(0, scatter, 20), 0 * k, 0 * k,
                                np.full(20, score)])
        tr = SimpleNamespace(meas=list(meas), born=0, clutter=0)
        test.measure(tr, 19)
        test.ended(tr, 3)
        return tr

    fast, slow = ended(3.0, 0.1, 11.0), ended(0.3, 0.1, 11.0)
    assert fast.speed == pytest.approx(3.0, abs=0.05) and slow.speed == pytest.approx(0.3, abs=0.05)
    assert fast.E <= test.rate and slow.E <= test.rate and slow.moved >= 1.0
    assert not test.clutter_like(fast) and test.clutter_like(slow)
    ended(0.0, 0.5, 9.0)                                        # fails the motion test
    assert sorted(test.ended_sample[:, 0]) == [9.0, 11.0]       # the slow point's; not the fast
    # with clutter_speed inf (the design before) the fast target joins the sample
    before = ClutterTest((512, 640), false_tracks=0.001, floor=1e-6, window=30, learn=0,
                         clutter_speed=np.inf)
    before.measure(fast, 19)
    assert before.clutter_like(fast)


def test_a_short_track_with_no_clutter_beside_it_meets_the_frames_clutter_density():
    # 4 hits on a line in 4 frames with no other region within the test's radius: by
    # the local count alone clutter could hardly make such a track (E far below the
    # rate); in frames holding 60 regions each it could, and the track is not confirmed
    test = ClutterTest((512, 640), false_tracks=0.001, floor=1e-6, window=30)
    k = np.arange(4.0)
    meas = np.column_stack([k, 100 + 3 * k, 200 + 0 * k])
    lonely, _ = test.expectation(meas, 4, 0)
    assert lonely < test.rate
    for _ in range(20):
        test.observe(60)
    crowded, _ = test.expectation(meas, 4, 0)
    assert crowded > test.rate
    # a target seen 20 frames in a row still passes in those frames
    k = np.arange(20.0)
    long_, _ = test.expectation(np.column_stack([k, 100 + 3 * k, 200 + 0 * k]), 20, 0)
    assert long_ < test.rate


def test_still_chance_is_the_f_test_of_zero_velocity():
    from scipy import stats
    # hits on a moving line with residuals of +-0.5 px (none is an outlier): F(2, 2(n-2))
    k = np.arange(10.0)
    r = 0.5 * (-1.0) ** k
    x, y = 3 + 0.2 * k + r, 7 - 0.1 * k - r
    vx, vy = np.polyfit(k, x, 1)[0], np.polyfit(k, y, 1)[0]
    ex, ey = x - np.polyval(np.polyfit(k, x, 1), k), y - np.polyval(np.polyfit(k, y, 1), k)
    F = (vx ** 2 + vy ** 2) * ((k - k.mean()) ** 2).sum() / 2 / ((ex ** 2 + ey ** 2).sum() / 16)
    assert still_chance(k, x, y) == pytest.approx(stats.f.sf(F, 2, 16), rel=1e-9)
    assert still_chance(k[:2], x[:2], y[:2]) == 1.0
    # a point that stays put: the chance is (nearly) uniform, within a factor 2 at 1 %
    g = np.random.default_rng(0)
    p = np.array([still_chance(np.arange(8), g.normal(0, 1.5, 8), g.normal(0, 1.5, 8))
                  for _ in range(3000)])
    assert 0.005 <= (p <= 0.01).mean() <= 0.02


def test_a_point_whose_centroid_wanders_is_not_a_track():
    # a bright point that stays put, its centroid scattered 1.5 px per axis frame to frame
    # (a peak wandering over a bright structure), beside a target at 1 px/frame: the
    # wander fits lines that move the 4.2 px of the first test, not significantly
    n, h, w = 80, 96, 128
    wandering = 0
    for seed in (1, 3):
        g = np.random.default_rng(seed)
        frames = g.normal(100, 3, (n, h, w)).astype(np.float32)
        for t in range(n):
            frames[t] += _blob((h, w), 90 + g.normal(0, 1.5), 60 + g.normal(0, 1.5), 1, 1, 30)
            frames[t] += _blob((h, w), 10 + t, 20 + 0.2 * t, 1, 1, 30)
        points, tracks = track(frames)
        assert len(tracks) == 1 and points["x"].max() > 80 and points["y"].max() < 40
        wandering += len(track(frames, motion_p=1.0)[1]) - 1
    assert wandering >= 2                          # without the significance test


def test_tail_share_is_one_to_the_median_then_an_exponential_tail():
    v = np.arange(1.0, 21.0)                              # median 10.5, excess mean 5
    assert tail_share(v, 3.0) == 1.0
    assert tail_share(v, 10.5 + 5.0) == pytest.approx(0.5 * np.exp(-1.0))
    assert tail_share([0.1, 0.2, 0.3], 5.0) == pytest.approx(1 / 3)  # too few: empirical


def test_guided_regions_search_a_confirmed_tracks_gate_below_the_frames_level():
    from irdetect.track.detector import guided_regions
    s = (_blob((60, 80), 20.2, 15.4, 1.2, 1.2, 3.8)      # near a track, under the level 5
         + _blob((60, 80), 60.0, 40.0, 1.2, 1.2, 3.8)    # as faint, near no track
         + _blob((60, 80), 40.0, 45.0, 1.2, 1.2, 9.0)).astype(np.float32)
    found = peak_regions(s, 5.0)
    assert len(found) == 1                               # the frame's level: the bright one
    centres = np.array([[21.0, 16.0], [41.0, 44.0], [70.0, 10.0]])
    more = guided_regions(s, found, centres, 3.0, radius=4.0)
    # only the first gate lacks a region and holds a peak at the lower level
    assert len(more) == 1
    whole = peak_regions(s, 3.0)
    same = whole[np.argmin(np.hypot(whole["x"] - 20.2, whole["y"] - 15.4))]
    for name in ("x", "y", "area", "grey", "contrast", "bx", "by", "bw", "bh"):
        assert more[name][0] == pytest.approx(same[name], abs=1e-9)
    assert len(guided_regions(s, found, centres[:1], 3.0, radius=0.5)) == 0
    assert len(guided_regions(s, found, np.zeros((0, 2)), 3.0, radius=4.0)) == 0


def _fading(rng, faint):
    """A point target (PSF sigma 1 px) at 1.6 px/frame over white noise of sigma 1: peak 8
    in frames 0-29, then ``faint``; 60 frames of 120 x 160."""
    g = np.random.default_rng(rng)
    n, h, w = 60, 120, 160
    frames = (100 + g.normal(0, 1.0, (n, h, w))).astype(np.float32)
    truth = np.zeros(n, [("frame", "<i8"), ("target", "<i8"), ("x", "<f8"), ("y", "<f8"),
                         ("amplitude", "<f8")])
    for t in range(n):
        x, y, a = 20 + 1.5 * t, 40 + 0.5 * t, (8.0 if t < 30 else faint)
        frames[t] += _blob((h, w), x, y, 1.0, 1.0, a).astype(np.float32)
        truth[t] = (t, 0, x, y, a)
    return frames, truth


@pytest.mark.parametrize("rng", [0, 5])
def test_a_target_fading_below_the_frames_level_keeps_feeding_its_track(rng):
    # at peak 1.8 the target's matched peak mostly falls under the frame's CFAR level
    # (3.9 local sigmas); its gate, searched at 3.6, still finds it (istd640-seq1-243's
    # target after frame 34); without the search the track coasts and dies unseen
    frames, truth = _fading(rng, 1.8)
    late = truth[truth["frame"] >= 30]
    found = {}
    for rate in (0.01, 0.0):
        points, tracks = track(frames, guided_rate=rate)
        assert len(tracks) == 1
        found[rate] = clear_mot(late, points[points["frame"] >= 30], gate=3.0)["matches"]
    assert found[0.01] >= 20 and found[0.0] <= 10


def test_measuring_tentative_tracks_together_gives_each_its_own_figures():
    # the tracker measures all its tentative tracks at once (padded to the longest):
    # tracks of 1, 2, 3 and 25 hits, moving, still and with an outlier, measured
    # together get the figures each gets alone, so the padding leaks nothing
    rng = np.random.default_rng(3)

    def tentative(n, vx, scatter, born):
        k = np.arange(n, dtype=float) + born
        meas = np.column_stack([k, 50 + vx * k + rng.normal(0, scatter, n),
                                80 - 0.5 * vx * k + rng.normal(0, scatter, n), 0 * k, 0 * k,
                                rng.uniform(3, 20, n)])
        if n > 5:
            meas[n // 2, 1] += 9.0                      # a noise peak taken in the gate
        return SimpleNamespace(meas=list(map(tuple, meas)), born=born, clutter=int(n))

    tracks = [tentative(n, v, s, b) for n, v, s, b in
              [(1, 0.0, 0.3, 24), (2, 1.0, 0.3, 20), (3, 2.0, 0.2, 19), (25, 0.4, 0.5, 0),
               (12, 0.0, 0.8, 10), (7, 3.0, 0.1, 14)]]
    together = ClutterTest((240, 320), false_tracks=0.001, floor=1e-6, window=30)
    together.measure_all(tracks, 24)
    got = [(t.E, t.moved, t.still, t.speed, t.score) for t in tracks]
    alone = ClutterTest((240, 320), false_tracks=0.001, floor=1e-6, window=30)
    for t, g in zip(tracks, got):
        alone.measure(t, 24)
        assert (t.E, t.moved, t.still, t.speed, t.score) == pytest.approx(g, rel=1e-12)
        meas = np.array(t.meas)
        if len(meas) >= 3:
            assert t.still == pytest.approx(still_chance(*meas[:, :3].T), rel=1e-12)
        assert t.score == np.median(meas[:, 5])
    assert got[0][:3] == (np.inf, 0.0, 1.0) and got[3][1] >= 1.0 and got[4][1] < 1.0


def test_a_target_slower_than_the_motion_test_per_window_is_confirmed_later():
    # a lone target at 0.12 px/frame moves 3.5 px in a 30-frame tentative life, under
    # test 1's 3 sqrt(2) sigma (4.2 px): with its chain and its motion significant it is
    # tested on with its hits and confirmed near frame 36 (before, it ended at frame 30
    # and started again from nothing, for ever); a point that stays put with the same
    # scatter is not
    from irdetect.track import REGION, FCMPMHTTracker

    rng = np.random.default_rng(2)

    def run(speed):
        test = ClutterTest((120, 160), false_tracks=0.001, floor=1e-6, window=30, learn=0,
                           score_floor=4.0)
        tracker = FCMPMHTTracker(confirm_window=30, confirm=test)
        for k in range(80):
            reg = np.zeros(1, REGION)
            reg[0] = (40 + speed * k + rng.normal(0, 0.05), 60 + rng.normal(0, 0.05), 9,
                      150, 100, 1.0, 39, 59, 3, 3)
            tracker.step(k, reg, (120, 160))
        return tracker.finish()

    slow = run(0.12)
    assert len(slow) == 1 and slow["frame_start"][0] == 0
    assert len(run(0.0)) == 0
