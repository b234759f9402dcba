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
