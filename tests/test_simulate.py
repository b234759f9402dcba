import numpy as np
import pytest

from irdetect.errors import InputError
from irdetect.simulate import load_scenario, simulate


def test_wan2008_preset_reproduces_the_papers_scene():
    s = load_scenario("wan2008")
    assert (s.height, s.width, s.n_targets) == (240, 320, 5) and s.n_frames >= 48
    frames, truth = simulate("wan2008", rng=0)
    assert frames.shape == (48, 240, 320)
    headings = set()
    for j in range(5):
        rows = truth[truth["target"] == j]
        dx, dy = np.diff(rows["x"]), np.diff(rows["y"])
        np.testing.assert_allclose(np.hypot(dx, dy), 1.0)  # 1 px/frame
        headings.add(round(float(np.degrees(np.arctan2(dy[0], dx[0]))) % 360))
    assert len(headings) == 5  # all in different directions


@pytest.mark.parametrize("snr", [3.0, 6.0])
def test_targets_are_where_truth_says_at_the_snr_asked(snr):
    sigma = 5.0
    frames, truth = simulate("wan2008", rng=1, snr=snr, noise_sigma=sigma, dtype="float32",
                             n_frames=60, background=100.0)
    # noise level: away from the targets the frames are N(background, sigma)
    assert frames[:, :20, :20].std() == pytest.approx(sigma, rel=0.05)
    assert frames[:, :20, :20].mean() == pytest.approx(100.0, abs=0.2)
    # peak amplitude: the background-subtracted value at the truth position, averaged over
    # frames (interpolating the Gaussian PSF back to its sub-pixel centre)
    t, x, y = truth["frame"], truth["x"], truth["y"]
    r, c = np.rint(y).astype(int), np.rint(x).astype(int)
    sampled = frames[t, r, c] - 100.0
    psf = np.exp(-((c - x) ** 2 + (r - y) ** 2) / (2 * 0.6 ** 2))
    assert np.mean(sampled / psf) == pytest.approx(snr * sigma, rel=0.08)
    assert np.all(truth["amplitude"] == snr * sigma)


def test_uint16_and_clutter_and_seed():
    a, ta = simulate("clutter", rng=5, dtype="uint16", background=1000.0)
    b, tb = simulate("clutter", rng=5, dtype="uint16", background=1000.0)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(ta, tb)
    assert a.dtype == np.uint16
    c, _ = simulate("clutter", rng=6, dtype="uint16", background=1000.0)
    assert not np.array_equal(a, c)
    # structured clutter is far stronger than the noise
    assert a.astype(float).std() > 4 * 4.0


def test_bad_scenarios_are_refused():
    with pytest.raises(InputError, match="unknown sequence scenario"):
        load_scenario("nope")
    with pytest.raises(InputError, match="unknown config key scenario.colour"):
        load_scenario("wan2008", colour=1)
    with pytest.raises(InputError, match="dtype"):
        load_scenario("wan2008", dtype="bool")


def test_psf_numbers_stated_in_the_docs():
    """docs/simulator.md: 99 % of the sampled energy in 3x3 px; peak 29 % / 50 % lower at
    half a pixel off in one / both axes."""
    from irdetect.simulate.sequence import _add_psf

    def render(x, y):
        frame = np.zeros((21, 21), np.float32)
        _add_psf(frame, x, y, 1.0, 0.6, 4)
        return frame

    centred = render(10.0, 10.0)
    assert centred[9:12, 9:12].sum() / centred.sum() == pytest.approx(0.99, abs=0.005)
    assert render(10.5, 10.0).max() == pytest.approx(1 - 0.29, abs=0.005)
    assert render(10.5, 10.5).max() == pytest.approx(1 - 0.50, abs=0.005)


def test_a_panning_shaking_camera_moves_the_scene_but_not_the_hot_pixels():
    # the clouds do not drift against the ground here, so the whole scene moves with the
    # camera (a drifting cloud field is a second motion, which the estimate then follows)
    frames, truth = simulate("clutter", rng=4, n_frames=30, camera_pan=(1.5, -0.5),
                             camera_jitter=0.5, dtype="float32", noise_sigma=0.5,
                             cloud_drift=[0.0, 0.0])
    from irdetect.camera import estimate_motion
    from irdetect.simulate.sequence import camera_offsets, load_scenario, target_paths

    s = load_scenario("clutter", n_frames=30, camera_pan=(1.5, -0.5), camera_jitter=0.5,
                      dtype="float32", noise_sigma=0.5, cloud_drift=[0.0, 0.0])
    rng = np.random.default_rng(4)
    target_paths(s, rng)
    expect = camera_offsets(s, rng)                 # the pan and the jitter drawn
    assert np.abs(expect - np.arange(30)[:, None] * np.array([1.5, -0.5])).max() <= 1.0
    # within 0.7 px: the straight horizon and 30 hot pixels held still in the image pull
    # a little (0.2 px without them; the simulator's bilinear sampling blurs each frame
    # by its own sub-pixel part, too)
    err = np.abs(estimate_motion(frames) - expect)
    assert err.max() < 0.7 and np.sqrt((err ** 2).mean()) < 0.35
    # the targets move with the scene (their scene velocity plus the pan, jitter on top)
    for j in np.unique(truth["target"]):
        rows = truth[truth["target"] == j]
        vx = np.polyfit(rows["frame"], rows["x"], 1)[0]
        assert abs(vx - 1.5) <= 1.5 + 0.1                       # clutter: 0.5-1.5 px/frame
    # hot pixels stay in the image: the brightest spikes over the 3x3 median are fixed
    import cv2
    spikes = [set(np.flatnonzero((f - cv2.medianBlur(f, 3)).ravel() > 30)) for f in frames[::10]]
    assert len(spikes[0] & spikes[1] & spikes[2]) >= 20


def test_paths_longer_than_the_frame_cross_it_whole_at_times_of_their_own():
    # a fast pan on a narrow frame: every path is longer than the frame across it
    from irdetect.simulate.sequence import load_scenario, target_paths

    s = load_scenario("wan2008", n_targets=8, width=300, height=100, n_frames=120,
                      camera_pan=(0.5, 2.0), speed=[1.0, 2.0], margin=5)
    paths = target_paths(s, np.random.default_rng(3))
    t = np.arange(s.n_frames)[:, None]
    x, y = paths[:, 0] + paths[:, 2] * t, paths[:, 1] + paths[:, 3] * t     # (T, n)
    inside = (x >= 5) & (x <= 294) & (y >= 5) & (y <= 94)
    # each crosses the 90 rows inside (0.5 px of rounding): 90 / vy frames
    assert (inside.sum(0) >= np.floor(89 / np.abs(paths[:, 3]))).all()
    # ... at a time of its own, not all through the centre at mid-sequence
    mid = (inside * t).sum(0) / inside.sum(0)
    assert np.ptp(mid) > 20


def test_camera_options_are_checked():
    with pytest.raises(InputError, match="camera_jitter"):
        load_scenario("wan2008", camera_jitter=-1.0)
    with pytest.raises(InputError, match="agc_period"):
        load_scenario("wan2008", agc_step=0.1, agc_period=0)
    with pytest.raises(InputError, match="agc_step"):
        load_scenario("wan2008", agc_step=-1.0)


def test_the_gain_control_switches_every_period_about_the_background():
    kw = dict(rng=4, n_frames=30, dtype="float32", cloud_amplitude=30.0)
    fixed, truth = simulate("wan2008", **kw)
    stepped, truth2 = simulate("wan2008", agc_step=0.2, agc_period=10, **kw)
    np.testing.assert_array_equal(truth, truth2)
    background = load_scenario("wan2008").background
    for t in range(30):
        gain = 1.2 if 10 <= t < 20 else 1.0
        np.testing.assert_allclose(stepped[t], gain * (fixed[t] - background) + background,
                                   atol=1e-3)


def test_a_new_target_count_takes_the_presets_first_directions():
    """--targets N on a preset with directions for its own 5 targets: the first N of them
    (N <= 5) or random ones (N > 5); it used to fail unless N was 5."""
    from irdetect.simulate.sequence import load_scenario

    assert load_scenario("wan2008", n_targets=3).directions == (0.0, 72.0, 144.0)
    assert load_scenario("wan2008", n_targets=8).directions == ()
    assert load_scenario("wan2008", n_targets=2, directions=[10.0, 20.0]).directions == \
        (10.0, 20.0)
