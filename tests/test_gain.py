"""The camera's gain control measured frame to frame and undone (``irdetect.gain``)."""

import dataclasses

import cv2
import numpy as np
import pytest

from irdetect.config import ProcessConfig
from irdetect.gain import SensorGain, frame_gain, normalise
from irdetect.metrics.detection import score_detections
from irdetect.pipeline import detect_sequence
from irdetect.pipeline.reader import Reader
from irdetect.simulate import simulate


def _scene(rng, size=(260, 300)):
    """A textured scene of grey levels 100 +- 30 (clouds of 4 px)."""
    texture = cv2.GaussianBlur(rng.standard_normal(size), (0, 0), 4)
    return 100.0 + 30.0 * texture / texture.std()


def _views(scene, origins, shape=(200, 240)):
    """Frames that show ``scene`` from the (x, y) origins: a scene point at p in the first
    is at p - (origin - first origin) in the others (camera offsets -origin)."""
    h, w = shape
    return np.stack([scene[y:y + h, x:x + w] for x, y in origins])


def test_frame_gain_is_the_ratio_of_spreads_on_the_registered_common_part():
    rng = np.random.default_rng(0)
    scene = _scene(rng)
    previous, frame = _views(scene, [(10, 20), (14, 17)])
    frame = 1.2 * (frame - 90.0) + 80.0 + rng.normal(0, 1.0, frame.shape)
    previous = previous + rng.normal(0, 1.0, previous.shape)
    g, mp, mf, r, n = frame_gain(previous, frame, shift=(-4, 3))
    assert g == pytest.approx(1.2, rel=0.01)
    assert mf == pytest.approx(1.2 * (mp - 90.0) + 80.0, abs=0.2)
    assert r > 0.99 and n > 9000
    # unregistered, the same frames correlate less; the gain is still their spread ratio
    assert frame_gain(previous, frame)[3] < 0.9


def test_frame_gain_leaves_out_the_clip_of_an_8_bit_frame():
    # the gain rises by 15 % about 100 and clips 6 % of the frame at 255 (3 % before):
    # the spreads of the whole frames differ by 11 %
    rng = np.random.default_rng(1)
    scene = _scene(rng) * 1.7 - 10
    previous = np.clip(np.rint(_views(scene, [(0, 0)])[0]), 0, 255)
    frame = np.clip(np.rint(1.15 * (previous - 100.0) + 100.0), 0, 255)
    assert (frame == 255).mean() > 0.05
    assert frame.std() / previous.std() < 1.12
    g = frame_gain(previous.astype(np.uint8), frame.astype(np.uint8))[0]
    assert g == pytest.approx(1.15, rel=0.005)


def test_sensor_gain_follows_steps_and_leaves_a_steady_camera_alone():
    rng = np.random.default_rng(2)
    scene = _scene(rng)
    origins = [(5 + 2 * t, 10 + t) for t in range(16)]     # the camera pans (2, 1) px/frame
    clean = _views(scene, origins) + rng.normal(0, 1.0, (16, 200, 240))
    offsets = -np.array(origins, float)
    gain = np.ones(16)
    gain[5:10] = 1.15                                       # the camera's AGC steps up ...
    gain[10:13] = 0.92                                      # ... down, and back
    stepped = (clean - 100.0) * gain[:, None, None] + 100.0 + 3.0 * (gain[:, None, None] < 1)
    # a gain that drifts 3 % is not a step: the background's own drift
    drifted = (clean - 100.0) * 1.03 ** (np.arange(16) // 8)[:, None, None] + 100.0
    assert np.all(SensorGain().update(clean, offsets) == (1.0, 0.0))
    assert np.all(SensorGain().update(drifted, offsets) == (1.0, 0.0))
    assert np.all(SensorGain(step=0).update(stepped, offsets) == (1.0, 0.0))
    g = SensorGain().update(stepped, offsets)
    np.testing.assert_allclose(g[:, 0], gain, rtol=0.01)
    # the frames taken back to frame 0's scale and level are the clean ones
    back = normalise(stepped, g)
    assert back.dtype == np.float32
    assert np.abs(back - clean).max(axis=(1, 2)).max() < 2.0
    # in blocks, as the reader gives them: the same
    streamed = SensorGain()
    np.testing.assert_allclose(np.concatenate([streamed.update(stepped[:7], offsets[:7]),
                                               streamed.update(stepped[7:], offsets[7:])]), g)


def test_sensor_gain_takes_no_step_from_noise():
    # frames of noise alone: their spread ratio wanders by a few per cent on a small frame,
    # which the standard error of the ratio (no texture: correlation 0) holds back
    rng = np.random.default_rng(3)
    frames = 50.0 + rng.normal(0, 4.0, (60, 24, 24))
    assert np.all(SensorGain().update(frames, np.zeros((60, 2))) == (1.0, 0.0))


def test_a_pan_over_a_horizon_registered_takes_no_step():
    # the camera pans 5 px/frame down a scene whose texture ends (a horizon coming into
    # view): the frames' common part, registered by the camera's offsets, keeps its
    # spread; unregistered (a motion the estimator missed) it loses 2-5 % a frame and the
    # steps add up to 0.89 (taken: docs/detection.md says why no correlation test holds
    # them back)
    rng = np.random.default_rng(5)
    scene = _scene(rng, size=(400, 240))
    scene[200:] = 100.0 + (scene[200:] - 100.0) * np.exp(-np.arange(200) / 12.0)[:, None]
    frames = np.stack([scene[5 * t:5 * t + 160] for t in range(30)])
    frames = frames + rng.normal(0, 1.0, frames.shape)
    offsets = np.stack([np.zeros(30), -5.0 * np.arange(30)], axis=1)
    g = SensorGain()
    assert np.all(g.update(frames, offsets) == (1.0, 0.0)) and g.summary() is None
    assert SensorGain().update(frames, np.zeros((30, 2)))[-1, 0] < 0.9


def test_the_reader_gives_the_frames_of_a_stepped_gain_back_on_frame_0s_scale():
    rng = np.random.default_rng(4)
    clean = np.clip(np.rint(_views(_scene(rng), [(8, 8)] * 30)
                            + rng.normal(0, 1.0, (30, 200, 240))), 0, 255)
    stepped = clean.copy()
    stepped[12:] = np.clip(np.rint(1.2 * (clean[12:] - 100.0) + 100.0), 0, 255)
    reader = Reader(stepped.astype(np.uint8), history=8, length=6)
    for a in range(0, 30, 6):
        window, history = reader.read(a, a + 6)
        assert len(history) == min(a, 8)
        expect = clean[a - len(history):a + 6]
        got = np.concatenate([history, window])
        if a + 6 <= 12:
            assert got.dtype == np.uint8         # no step yet: the raw frames as stored
        else:
            assert got.dtype == np.float32
        assert np.abs(got - expect).mean() < 0.5
    assert reader.gains[11, 0] == 1.0 and reader.gains[12, 0] == pytest.approx(1.2, rel=0.01)
    off = Reader(stepped.astype(np.uint8), history=8, length=6, gain_step=0)
    assert off.read(12, 18)[0].dtype == np.uint8


def test_the_reader_clips_every_frame_to_the_range_all_of_them_can_show():
    # a bright patch at 240 over 100 grey levels saturates at 255 after a step of +15 %:
    # taken back it reads (255 - 100) / 1.15 + 100 = 234.8, and a background of the frames
    # before the step would leave 5 grey levels of it in those after; every frame of a
    # window that spans the step is clipped to 234.8 instead
    rng = np.random.default_rng(5)
    clean = _views(_scene(rng), [(8, 8)] * 24) + rng.normal(0, 1.0, (24, 200, 240))
    clean[:, 80:100, 100:120] = 240.0
    stepped = clean.copy()
    stepped[12:] = 1.15 * (clean[12:] - 100.0) + 100.0
    stepped = np.clip(np.rint(stepped), 0, 255).astype(np.uint8)
    assert (stepped[12:, 80:100, 100:120] == 255).all()
    reader = Reader(stepped, history=8, length=6)
    for a in (0, 6):
        reader.read(a, a + 6)
    window, history = reader.read(12, 18)
    before, after = history[-1, 80:100, 100:120], window[0, 80:100, 100:120]
    assert np.abs(after - before).max() < 0.5
    assert after.mean() == pytest.approx(155 / reader.gains[12, 0] + 100, abs=1.0)
    # the frames taken back alone disagree there by the clip's 5 grey levels
    assert (normalise(stepped[4:18], reader.gains[4:18])[-1, 80:100, 100:120]
            < normalise(stepped[4:18], reader.gains[4:18])[7, 80:100, 100:120] - 4).all()


def test_only_a_frame_with_a_pixel_at_the_limit_bounds_the_range():
    # a step down to x0.6 (as easy3's recorded gain control takes): a target of raw 250
    # after it is 350 grey levels on frame 0's scale, beyond what frame 0 could show, but
    # no frame holds a pixel at 255, so nothing is a bound and nothing is clipped (the
    # range every frame can show, 0-255, had taken it down to 255, to the clouds beside it)
    rng = np.random.default_rng(6)
    clean = _views(_scene(rng), [(8, 8)] * 24) + rng.normal(0, 1.0, (24, 200, 240))
    stepped = clean.copy()
    stepped[12:] = 0.6 * (clean[12:] - 100.0) + 100.0
    stepped = np.clip(np.rint(stepped), 1, 254).astype(np.uint8)
    stepped[12:, 60, 70] = 250
    gains = np.tile([1.0, 0.0], (24, 1))
    gains[12:] = 0.6, 40.0                 # raw = 0.6 value + 40 after the step
    got = normalise(stepped, gains, (0, 255))
    assert got[12:, 60, 70] == pytest.approx((250 - 40) / 0.6)
    assert np.array_equal(got, normalise(stepped, gains))
    # a frame before the step holding a pixel at 255 bounds every frame at 255
    stepped[3, 10, 10] = 255
    assert normalise(stepped, gains, (0, 255))[12:, 60, 70] == pytest.approx(255.0)


@pytest.mark.parametrize("step", [0.3, -0.25])
def test_a_gain_that_steps_every_18_frames_does_not_cost_the_targets(step):
    # dim targets (SNR 3) under clouds of 120 grey levels: each step leaves 30 grey levels
    # of cloud in a background that spans both gains, unless the steps are undone
    # (a run: 22 of 30 targets as with a fixed gain, 3 of 30 without the correction)
    found = {}
    for agc, gain_step in ((0.0, 0.05), (step, 0.05), (step, 0.0)):
        frames, truth = simulate("clutter", rng=0, n_frames=72, snr=3, cloud_amplitude=120,
                                 agc_step=agc, agc_period=18)
        config = ProcessConfig()
        config = dataclasses.replace(config, suppress=dataclasses.replace(
            config.suppress, gain_step=gain_step))
        out = detect_sequence(frames, config)
        found[agc, gain_step] = score_detections(out["detections"], truth, n_frames=72,
                                                 length=12, step=12, shape=frames.shape[1:])
    fixed, undone, kept = found[0.0, 0.05], found[step, 0.05], found[step, 0.0]
    assert fixed["detected"] >= 18
    assert undone["detected"] >= fixed["detected"] - 1 and undone["false"] <= fixed["false"]
    assert kept["detected"] <= fixed["detected"] - 10


@pytest.mark.parametrize("step", [-0.1, 1.0, 2.0])
def test_a_gain_step_out_of_range_is_refused_by_both_commands(tmp_path, step):
    from irdetect.errors import InputError
    from irdetect.pipeline import check_config
    from irdetect.track.detector import detector_blocks
    config = ProcessConfig()
    config = dataclasses.replace(config, suppress=dataclasses.replace(config.suppress,
                                                                     gain_step=step))
    with pytest.raises(InputError, match="gain_step must be in"):
        check_config(config, tmp_path / "c.toml")
    with pytest.raises(ValueError, match="gain_step must be in"):
        next(detector_blocks(np.zeros((20, 32, 32), np.float32),
                             suppression={"gain_step": step}))
