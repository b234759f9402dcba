"""The camera's image motion, measured once per frame (irdetect.camera)."""

import cv2
import numpy as np
import pytest

from irdetect import tables
from irdetect.camera import CameraMotion, estimate_motion
from irdetect.pipeline import detect_sequence


def scene_frames(offsets, shape=(160, 200), detail=2.0, noise=2.0, hot=20, rng=0):
    """Frames of a textured scene seen by a camera whose image offsets are ``offsets``
    (T, 2): a scene point at p in frame 0 is at p + offsets[t] in frame t; ``hot`` pixels
    fixed in the image."""
    rng = np.random.default_rng(rng)
    h, w = shape
    pad = int(np.abs(offsets).max()) + 8
    big = cv2.GaussianBlur(rng.normal(size=(h + 2 * pad, w + 2 * pad)).astype(np.float32),
                           (0, 0), detail)
    big = 100 + 15 * big / big.std()
    frames = np.stack([cv2.getRectSubPix(big, (w, h), (pad + (w - 1) / 2 - dx,
                                                         pad + (h - 1) / 2 - dy))
                       for dx, dy in offsets])
    frames += rng.normal(0, noise, frames.shape).astype(np.float32)
    idx = rng.choice(h * w, hot, replace=False)
    frames.reshape(len(frames), -1)[:, idx] += 80
    return frames


def pan(n, velocity, jitter=0.0, rng=1):
    rng = np.random.default_rng(rng)
    c = np.arange(n)[:, None] * np.asarray(velocity, float)
    c += rng.uniform(-jitter, jitter, c.shape)
    return c - c[0]


@pytest.mark.parametrize("shape", [(64, 64), (160, 200), (256, 256), (480, 640)])
@pytest.mark.parametrize("velocity, jitter", [((0.0, 0.0), 0.0), ((0.4, -0.3), 0.0),
                                              ((2.5, 1.5), 1.0), ((-3.0, 0.0), 0.5)])
def test_pan_and_jitter_are_recovered(shape, velocity, jitter):
    truth = pan(50, velocity, jitter)
    est = estimate_motion(scene_frames(truth, shape))
    err = np.abs(est - truth)
    # 50 frames at 3 px/frame: the keyframe moves on several times on the small frames
    # (64 x 64: 0.4 px rms there, a 32-px crop to refine on; 0.1 or less on the others)
    small = min(shape) < 100
    assert np.sqrt((err ** 2).mean()) < (0.5 if small else 0.15) and err.max() < 1.2


def test_hot_pixels_do_not_pin_the_estimate_and_noise_gives_none():
    truth = pan(30, (0.3, 0.2))
    est = estimate_motion(scene_frames(truth, hot=400))
    assert np.abs(est - truth).max() < 0.3
    noise = np.random.default_rng(3).normal(100, 3, (20, 96, 96)).astype(np.float32)
    assert np.abs(estimate_motion(noise)).max() < 1e-9         # nothing to register on
    flat = np.zeros((5, 32, 32), np.float32)
    assert np.abs(estimate_motion(flat)).max() == 0.0


def test_the_grey_level_scale_does_not_matter():
    """Frames of spread 1e9 (a float export in physical units) register as the same frames
    do in grey levels, without float32 overflow in the cross power (it overflowed, with
    RuntimeWarnings, from a spread of about 2e7)."""
    import warnings

    frames = scene_frames(pan(24, (1.2, -0.7), 0.3))
    est = estimate_motion(frames)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for scale in (1e-6, 1e8):
            np.testing.assert_allclose(estimate_motion(frames * np.float32(scale)), est,
                                       atol=1e-3)


def test_streaming_in_pieces_equals_one_call():
    frames = scene_frames(pan(24, (1.2, -0.7), 0.3))
    whole = estimate_motion(frames)
    cm = CameraMotion(frames.shape[1:])
    parts = np.concatenate([cm.update(frames[a:a + 7]) for a in range(0, 24, 7)])
    np.testing.assert_array_equal(parts, whole)


def test_results_carry_the_camera_of_every_frame():
    truth = pan(48, (0.5, 0.25))
    out = detect_sequence(scene_frames(truth, (96, 128)))
    cam = out["camera"]
    assert cam.dtype == tables.CAMERA and cam["frame"].tolist() == list(range(48))
    assert np.abs(np.column_stack([cam["dx"], cam["dy"]]) - truth).max() < 0.3


def test_gradient_gain_is_white_noises():
    # GRADIENT_GAIN: E[gx^2] of the band-passed frame's Sobel / 8 (lone_edge's, unclipped)
    # per squared spread of the 3x3 high-pass, on white noise reduced 0-3 times
    from irdetect.camera import GRADIENT_GAIN, _Gradients, _noise_spread, _reduce
    for levels, gain in enumerate(GRADIENT_GAIN):
        z = np.random.default_rng(5).normal(0, 1, (512 << levels, 512 << levels))
        r = _reduce(z.astype(np.float32), levels)
        g = _Gradients(r, clip=False)
        k = 0.5 * (np.mean(g.gx[16:-16, 16:-16] ** 2) + np.mean(g.gy[16:-16, 16:-16] ** 2))
        assert k / _noise_spread(r) ** 2 == pytest.approx(gain, rel=0.1)


def _horizon(offsets, shape=(240, 320), tilt=0.1, step=60.0, noise=5.0, rng=0):
    """A bright ground below a straight horizon (slope ``tilt``) over noise, seen by a camera
    whose image offsets are ``offsets`` (T, 2)."""
    g = np.random.default_rng(rng)
    h, w = shape
    yy, xx = np.mgrid[:h, :w].astype(np.float32)
    frames = []
    for dx, dy in offsets:
        # the scene point (x, y) is at (x + dx, y + dy): the horizon y = 110 + tilt x
        edge = (yy - dy) - (110 + tilt * (xx - dx))
        frames.append(100 + step / (1 + np.exp(-edge / 0.8)))
    frames = np.stack(frames).astype(np.float32)
    return frames + g.normal(0, noise, frames.shape).astype(np.float32)


def test_a_lone_horizon_is_followed_across_a_gain_step():
    # the camera's gain control steps by 25 % about the sky's level at frame 12 and back
    # at frame 24: the profile's fit takes the frame's gain and level beside the shift (it
    # had read a step as 1.2 px of motion across the edge, bench_unseen's scene 92)
    truth = pan(36, (0.0, -1.5))
    frames = _horizon(truth, noise=2.0)
    gain = np.where((np.arange(36) // 12) % 2 == 1, 1.25, 1.0)[:, None, None]
    stepped = ((frames - 100.0) * gain + 100.0).astype(np.float32)
    n = np.array([-0.1, 1.0]) / np.hypot(0.1, 1.0)
    steps = np.diff(estimate_motion(stepped) - truth, axis=0) @ n
    assert np.abs(steps).max() < 0.2


def test_a_lone_horizon_gives_the_camera_across_it():
    # a pan over a horizon and featureless sky: the motion across the edge is measured,
    # along it the camera is taken to hold still (it cannot be told); phase correlation
    # and the 2-D fit had drifted tens of px along unseen scenes' horizons
    from irdetect.camera import _reduce, lone_edge
    truth = pan(40, (1.5, -2.0))
    frames = _horizon(truth)
    normal = lone_edge(_reduce(frames[0], 1), 1)
    assert normal is not None and abs(abs(normal[1]) - 1 / np.hypot(1, 0.1)) < 0.01
    est = estimate_motion(frames)
    n = np.array([-0.1, 1.0]) / np.hypot(0.1, 1.0)
    across = (est - truth) @ n
    assert np.abs(across).max() < 0.5
    # a textured scene is no lone edge, nor a short bright bar over noise (a streak: the
    # camera would follow it)
    tex = scene_frames(truth[:1])[0]
    assert lone_edge(_reduce(tex, 1), 1) is None
    yy, xx = np.mgrid[:240, :320]
    bar = (100 + 30 * np.exp(-0.5 * (((xx - 80) / 8.0) ** 2 + ((yy - 60) / 0.8) ** 2))
           + np.random.default_rng(2).normal(0, 2, (240, 320))).astype(np.float32)
    assert lone_edge(_reduce(bar, 1), 1) is None
