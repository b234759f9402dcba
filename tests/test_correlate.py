"""Bidirectional correlation: constant-velocity targets linked, unrelated points rejected."""

import numpy as np
import pytest

from irdetect.correlate import correlate
from irdetect.tables import SEGMENT


def _pts(*xy):
    return np.array(xy, float).reshape(-1, 2)


@pytest.mark.parametrize("vx, vy", [(1.0, 0.0), (-0.7, 0.7), (0.0, -1.2), (0.0, 0.0)])
def test_links_a_constant_velocity_target(vx, vy):
    p = np.array([100.0, 80.0])
    v = 12 * np.array([vx, vy])
    c = correlate(_pts(p), _pts(p + v + [0.4, -0.3]), _pts(p + 2 * v), step=12, min_score=0)
    assert len(c.segments) == 1 and c.segments.dtype == SEGMENT
    assert c.segments["vx"][0] == pytest.approx(vx) and c.segments["vy"][0] == pytest.approx(vy)
    assert c.index.tolist() == [[0, 0, 0]]
    assert c.confirmed(1, 1).all()


def test_rejects_three_unrelated_points():
    c = correlate(_pts(20, 20), _pts(120, 60), _pts(40, 200), step=12, min_score=0)
    assert len(c.segments) == 0 and c.segments.dtype == SEGMENT


def test_rejects_a_bent_chain_unless_paper_mode():
    # within the motion bound each step, but turning 90 degrees: not constant velocity
    a, b, c3 = _pts(50, 50), _pts(70, 50), _pts(70, 70)
    assert len(correlate(a, b, c3, step=12, min_score=0).segments) == 0
    assert len(correlate(a, b, c3, step=12, min_score=0, constant_velocity=False,
                         resolve="all").segments) == 1


def test_ambiguity_resolution_modes():
    # two targets 6 px apart moving in parallel: 'all' also links across them
    p1 = _pts([50, 50], [50, 56])
    p2 = p1 + [12, 0]
    p3 = p1 + [24, 0]
    kw = dict(step=12, min_score=0, constant_velocity=False, max_speed=1.5)
    every = correlate(p1, p2, p3, resolve="all", **kw)
    unique = correlate(p1, p2, p3, resolve="unique", **kw)
    cost = correlate(p1, p2, p3, resolve="cost", **kw)
    assert len(every.segments) == 8
    assert len(unique.segments) == 0            # the paper relies on uniqueness: none left
    assert sorted(map(tuple, cost.index)) == [(0, 0, 0), (1, 1, 1)]


def test_score_threshold_uses_point_scores():
    pts = [np.zeros(1, dtype=[("x", "f8"), ("y", "f8"), ("score", "f8")]) for _ in range(3)]
    for i, p in enumerate(pts):
        p["x"], p["y"], p["score"] = 10 + 12 * i, 10, 4.0
    assert len(correlate(*pts, step=12, min_score=3.9).segments) == 1
    assert len(correlate(*pts, step=12, min_score=4.5).segments) == 0
    assert correlate(*pts, step=12, min_score=0).segments["score"][0] == pytest.approx(4.0)


def test_empty_inputs():
    c = correlate(_pts(), _pts(1, 1), _pts(), step=12)
    assert len(c.segments) == 0 and c.index.shape == (0, 3)


@pytest.mark.parametrize("kwargs, name", [
    ({"step": 0}, "step"), ({"max_speed": -1}, "max_speed"), ({"tolerance": -1}, "tolerance"),
    ({"max_deviation": 0}, "max_deviation"), ({"resolve": "best"}, "resolve"),
    ({"min_score": float("nan")}, "min_score"), ({"screen": -0.1}, "screen"),
    ({"screen": 1.5}, "screen")])
def test_bad_parameters_are_named(kwargs, name):
    args = {"step": 12, **kwargs}
    with pytest.raises(ValueError, match=name):
        correlate(_pts(1, 1), _pts(1, 1), _pts(1, 1), **args)


def _faint_target_evidence(seed, snr=2.0, psf=0.6, noise=4.0, v=(0.8, -0.6)):
    """36 noise frames with one Gaussian point moving at v px/frame; its true track."""
    from irdetect.verify import Evidence, matched_frame, noise_level, standardise

    rng = np.random.default_rng(seed)
    h, w = 64, 96
    t = np.arange(36)
    track = np.column_stack([30 + v[0] * t, 40 + v[1] * t])
    yy, xx = np.mgrid[:h, :w]
    frames = rng.normal(0, noise, (36, h, w)).astype(np.float32)
    for i, (x, y) in enumerate(track):
        frames[i] += snr * noise * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * psf ** 2))
    matched = [f for k in range(3)
               for f in standardise([matched_frame(r, psf) for r in frames[12 * k:12 * k + 12]])]
    ev = Evidence(frames=matched, index=t, times=(11.0, 23.0, 35.0), report=(5.5, 17.5, 29.5),
                  sigma=noise_level(matched))
    return ev, track


@pytest.mark.parametrize("seed", [0, 1])
def test_verification_keeps_a_faint_target_and_rejects_a_noise_chain(seed):
    ev, track = _faint_target_evidence(seed)
    # fused points a little off the track (as the dp merit gives them), and a straight
    # chain of 3 points where there is only noise
    off = np.array([[0.7, -0.5], [-0.6, 0.4], [0.5, 0.6]])
    target = [track[int(t)] + off[i] for i, t in enumerate(ev.times)]
    noise = [np.array([70.0, 15.0]) + i * np.array([-6.0, 9.0]) for i in range(3)]
    pts = [_pts(target[i], noise[i]) for i in range(3)]
    c = correlate(*pts, step=12, evidence=ev, verify=7.0, min_score=0)
    assert c.index.tolist() == [[0, 0, 0]]
    assert c.significance[0] > 7.0
    # the verified positions lie on the true track at the windows' middles
    for i, t in enumerate(ev.report):
        assert np.hypot(*(c.positions[0, i] - track[int(t)] - [0.5 * 0.8, -0.5 * 0.6])) < 1.0
    assert np.hypot(c.segments["vx"][0] - 0.8, c.segments["vy"][0] + 0.6) < 0.05
    # the same chains without evidence: both kept (nothing tells them apart)
    assert len(correlate(*pts, step=12, min_score=0).segments) == 2
    # verify = 0 is the unverified correlation even with evidence
    assert len(correlate(*pts, step=12, evidence=ev, verify=0.0, min_score=0).segments) == 2


@pytest.mark.parametrize("seed", range(6))
def test_verification_climbs_to_the_track_from_a_poor_fit(seed):
    # 3 points whose line is 1.6 px and 0.13 px/frame off the target's track (at the
    # ends of 36 frames: 2.3 px more): the hill climb reaches the track; one 3 x 3 x 3 x 3 grid
    # per step (the earlier search) reached 0.075 px/frame
    from irdetect.verify import _sample_sum, track_significance

    ev, track = _faint_target_evidence(seed, snr=3.0)
    tm = float(np.mean(ev.index))
    err_c, err_v = np.array([1.3, -0.9]), np.array([0.1, -0.08])
    pts = np.stack([track[int(t)] + err_c + err_v * (t - tm) for t in ev.times])[None]
    z, c, v = track_significance(ev, pts)
    true_c, true_v = track[0] + np.array([0.8, -0.6]) * tm, np.array([0.8, -0.6])
    assert np.hypot(*(v[0] - true_v)) < 0.03
    assert np.hypot(*(c[0] - true_c)) < 0.4
    frames = [np.stack(ev.frames)]
    dts = (np.asarray(ev.index) - tm).astype(np.float32)
    at_truth = _sample_sum(frames, dts, true_c[None, None], true_v[None, None])[0, 0]
    assert z[0] >= 0.95 * at_truth / (ev.sigma * np.sqrt(36))


def test_verification_significance_of_pure_noise_stays_low():
    from irdetect.verify import track_significance

    ev, _ = _faint_target_evidence(3, snr=0.0)
    rng = np.random.default_rng(5)
    start = rng.uniform(20, 60, (200, 1, 2))
    vel = rng.uniform(-1, 1, (200, 1, 2))
    pts = start + vel * np.array([11.0, 23.0, 35.0])[None, :, None]
    z, c, v = track_significance(ev, np.clip(pts, 2, 60))
    assert z.shape == (200,) and c.shape == v.shape == (200, 2)
    assert z.max() < 5.0


def test_bad_evidence_and_verify_are_named():
    with pytest.raises(ValueError, match="verify"):
        correlate(_pts(1, 1), _pts(1, 1), _pts(1, 1), step=12, verify=-1)
    with pytest.raises(ValueError, match="evidence"):
        correlate(_pts(1, 1), _pts(1, 1), _pts(1, 1), 12, "frames")


def test_verification_rejects_a_moving_edge():
    # clutter residual that moves coherently (an edge 15 px long) integrates as well as
    # a target along its track, but it is as strong 3 px beside the track: not a point
    from irdetect.verify import Evidence, matched_frame, noise_level, standardise

    rng = np.random.default_rng(4)
    h, w = 64, 96
    yy, xx = np.mgrid[:h, :w]
    frames = rng.normal(0, 4.0, (36, h, w)).astype(np.float32)
    for i in range(36):
        x = 30 + 0.8 * i
        frames[i] += 16.0 * np.exp(-((xx - x) ** 2) / (2 * 0.6 ** 2)) * (np.abs(yy - 32) <= 7)
    matched = [f for k in range(3)
               for f in standardise([matched_frame(r, 0.6) for r in frames[12 * k:12 * k + 12]])]
    ev = Evidence(frames=matched, index=np.arange(36), times=(11.0, 23.0, 35.0),
                  report=(5.5, 17.5, 29.5), sigma=noise_level(matched))
    pts = [_pts(30 + 0.8 * t, 32.0) for t in ev.times]
    assert len(correlate(*pts, step=12, evidence=ev, verify=6.5, min_score=0).segments) == 0
    # rejected by the point test, not for lack of energy: along its track it integrates
    from irdetect.verify import track_significance
    z, c, v = track_significance(ev, np.stack(pts, axis=1))
    assert z[0] > 6.5


@pytest.mark.parametrize("shape, bilinear, atol", [((12, 40, 30), True, 2e-4),
                                                   ((12, 40, 30), False, 2e-4),
                                                   ((5, 3000, 12), True, 2e-3)])
def test_track_sums_match_direct_interpolation(shape, bilinear, atol):
    # the compiled samplers (``irdetect.kernels.sampling``: the bilinear sums, and the
    # coarse stage's nearest-pixel 3 x 3 grids) against scipy's interpolation, positions
    # clamped to the frame, on small and on tall frames (float32 positions near row 3000
    # keep 1/4000 px: the looser tolerance)
    from scipy.ndimage import map_coordinates

    from irdetect.verify import _GRID, _grid_sums, _kernel_args, _sample_sum, _three
    rng = np.random.default_rng(5)
    m, h, w = shape
    blocks = [rng.normal(size=shape).astype(np.float32) for _ in range(2)]
    dts = (np.arange(2 * m) - (2 * m - 1) / 2).astype(np.float32)
    if bilinear:
        cc = np.column_stack([rng.uniform(-3, w + 3, 40), rng.uniform(-3, h + 3, 40)])
        cc = cc.reshape(8, 5, 2)
        vv = rng.uniform(-0.8, 0.8, (8, 5, 2))
        got = _sample_sum(blocks, dts, cc, vv)
    else:
        c = np.column_stack([rng.uniform(-3, w + 3, 8), rng.uniform(-3, h + 3, 8)])
        v = rng.uniform(-0.8, 0.8, (8, 2))
        d32, shift, cap = _kernel_args(dts)
        got = _grid_sums(_three(blocks), d32, c, v, (0.0,), shift, cap)
        cc = c[:, None, :] + _GRID[None]
        vv = np.repeat(v[:, None, :], 9, 1)
    frames = np.concatenate(blocks)
    want = np.zeros(got.shape)
    for f, dt in enumerate(dts):
        x = cc[..., 0] + vv[..., 0] * dt
        y = cc[..., 1] + vv[..., 1] * dt
        if not bilinear:
            x, y = np.rint(x), np.rint(y)
        want += map_coordinates(frames[f].astype(np.float64),
                                [np.clip(y, 0, h - 1).ravel(), np.clip(x, 0, w - 1).ravel()],
                                order=1, mode="nearest").reshape(got.shape)
    assert got.shape == ((8, 5) if bilinear else (8, 9))
    np.testing.assert_allclose(got, want, atol=atol)


def test_a_window_fewer_frames_on_is_predicted_at_its_own_time():
    # the tail window 5 frames after the window before it (``gap``): a point moving 1
    # px/frame is at 27, not at 34 where equally spaced windows would put it
    one, two = np.array([[10.0, 10.0]]), np.array([[22.0, 10.0]])
    c = correlate(one, two, np.array([[27.0, 10.0]]), 12, gap=5, min_score=0,
                  max_deviation=2.0)
    assert len(c.segments) == 1 and float(c.segments["vx"][0]) == pytest.approx(1.0)
    assert len(correlate(one, two, np.array([[34.0, 10.0]]), 12, gap=5, min_score=0,
                         max_deviation=2.0).segments) == 0
    assert len(correlate(one, two, np.array([[34.0, 10.0]]), 12, min_score=0,
                         max_deviation=2.0).segments) == 1
    with pytest.raises(ValueError, match="gap"):
        correlate(one, two, two, 12, gap=0)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("gaps", [(12, 12), (12, 5)])
def test_straight_chains_are_the_full_join_filtered_in_its_order(seed, gaps):
    # the lookup around the constant-velocity prediction (``_chains(deviation=)``; 2 p2 -
    # p1 for equally spaced windows, p2 + (p2 - p1) 5 / 12 for a tail window 5 frames on)
    # returns the chains of the full join that the constant-velocity test keeps, in the
    # same order
    from irdetect.correlate import _chains

    ratio = gaps[1] / gaps[0]
    bounds = (30.0, 30.0 * ratio)
    rng = np.random.default_rng(seed)
    pts = [rng.uniform(0, 200, (int(rng.integers(0, 120)), 2)) for _ in range(3)]

    def deviation(chains):
        p1, p2, p3 = (pts[i][chains[:, i]] for i in range(3))
        return np.hypot(*(p3 - p2 - (p2 - p1) * ratio).T) if len(chains) else np.zeros(0)

    full = _chains(pts, bounds)
    assert (np.abs(pts[2][full[:, 2]] - pts[1][full[:, 1]]) <= bounds[1]).all()
    want = full[deviation(full) <= 12.0]
    got = _chains(pts, bounds, 12.0, ratio)
    np.testing.assert_array_equal(got[deviation(got) <= 12.0], want)


def test_chains_per_point_bounds_the_verified_chains_and_keeps_the_target():
    # a target's chain among 30 noise points per frame: with chains_per_point 1 far
    # fewer chains reach the verification, and the target's is still confirmed
    import irdetect.correlate as C

    ev, track = _faint_target_evidence(0, snr=3.0)
    rng = np.random.default_rng(1)
    pts = []
    for t in ev.times:
        noise = rng.uniform(2, 60, (30, 2))
        p = np.zeros(31, dtype=[("x", "f8"), ("y", "f8"), ("score", "f8")])
        p["x"], p["y"] = np.r_[track[int(t)][0], noise[:, 0]], np.r_[track[int(t)][1], noise[:, 1]]
        p["score"] = np.r_[6.0, rng.uniform(3.5, 6.0, 30)]
        pts.append(p)
    seen = []
    original = C.verify_tracks

    def counting(evidence, points, **kw):
        seen.append(len(points))
        return original(evidence, points, **kw)

    C.verify_tracks = counting
    try:
        every = correlate(*pts, 12, ev, max_speed=1.0, chains_per_point=0)
        few = correlate(*pts, 12, ev, max_speed=1.0, chains_per_point=1)
    finally:
        C.verify_tracks = original
    assert seen[1] < seen[0] / 2
    for corr in (every, few):
        assert (corr.index == 0).all(axis=1).any()
    with pytest.raises(ValueError, match="chains_per_point"):
        correlate(*pts, 12, ev, chains_per_point=-1)
