"""The noise scale's floor at the frames' quantisation (``irdetect.verify.quantisation_floor``).

A lossy video codec copies the blocks of a still scene bit for bit from frame to frame, and
an 8-bit recording of a quiet scene repeats its grey levels: the robust scale of such a
residual is 0, and every grey level that changes became a local SNR of 1e3-1e6 (an H.264
clip of istd640-seq2-204: a false track at 924,302, the target at 4,211,591).
"""

import cv2
import numpy as np
import pytest

from irdetect.pipeline import detect_sequence
from irdetect.track import track
from irdetect.verify import matched_frame, quantisation_floor, standardise


@pytest.mark.parametrize("smooth", [0.0, 0.6, 1.0, 2.0])
def test_floor_is_the_scale_of_matched_quantisation_noise(smooth):
    # the definition: uniform errors of +-0.5 grey level per pixel through the matched
    # filter have the standard deviation the floor states
    rng = np.random.default_rng(0)
    q = rng.uniform(-0.5, 0.5, (512, 512)).astype(np.float32)
    measured = float(matched_frame(q, smooth)[16:-16, 16:-16].std())
    frame = np.full((8, 8), 100, np.uint8)
    assert quantisation_floor(frame, smooth) == pytest.approx(measured, rel=0.03)
    assert quantisation_floor(frame.astype(np.uint16), smooth) == \
        quantisation_floor(frame.astype(np.int32), smooth)


def test_float_frames_of_whole_grey_levels_have_the_floor_and_others_none():
    whole = np.arange(64, dtype=np.float64).reshape(8, 8)     # a MATLAB double of 8 bits
    assert quantisation_floor(whole, 0.6) == quantisation_floor(whole.astype(np.uint8), 0.6)
    assert quantisation_floor(whole + 0.25, 0.6) == 0.0          # a radiometric export
    assert quantisation_floor(np.full((4, 4), np.nan, np.float32), 0.6) == 0.0


def test_standardise_floors_a_tile_without_measured_noise():
    # one grey level at one pixel of frames that are otherwise exactly 0: without the
    # floor the MAD scale is 0 (float32's tiny) and the pixel 1e37 sigmas; with it, the
    # matched pixel in units of the quantisation's noise
    frames = np.zeros((12, 96, 96), np.float32)
    frames[5, 40, 50] = 1.0
    matched = [matched_frame(f, 0.6) for f in frames]
    bare = standardise([m.copy() for m in matched])
    floor = quantisation_floor(np.zeros((2, 2), np.uint8), 0.6)
    floored = standardise([m.copy() for m in matched], floor=floor)
    assert bare[5].max() > 1e30
    assert floored[5].max() == pytest.approx(matched[5].max() / floor, rel=1e-5)
    # a single grey level is no detection: under the per-frame path's CFAR level (4.2-4.5)
    assert 2.5 < floored[5].max() < 4.0


def _still_scene(n=48, h=128, w=160, seed=3):
    """Bit-identical uint8 frames of a textured still scene (a codec's skipped blocks),
    in which isolated pixels step by one grey level now and then (the codec's changes),
    and, when asked, a target."""
    rng = np.random.default_rng(seed)
    scene = cv2.GaussianBlur(rng.uniform(40, 120, (h, w)).astype(np.float32), (0, 0), 3)
    frames = np.repeat(np.round(scene).astype(np.uint8)[None], n, axis=0)
    t, y, x = rng.integers(0, n, 60), rng.integers(0, h, 60), rng.integers(0, w, 60)
    frames[t, y, x] += 1
    return frames


def _with_target(frames, amplitude=25.0):
    out = frames.astype(np.float32)
    yy, xx = np.mgrid[:out.shape[1], :out.shape[2]]
    for t in range(len(out)):
        x, y = 30 + 1.5 * t, 40 + 0.5 * t
        out[t] += amplitude * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * 0.8 ** 2))
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("dtype", [np.uint8, np.float64])
def test_process_reports_sane_local_snrs_on_a_bit_exact_still_scene(dtype):
    frames = _with_target(_still_scene()).astype(dtype)
    out = detect_sequence(frames)
    det = out["detections"]
    assert len(det) >= 3                        # the target, in most of its 4 windows
    on_target = np.hypot(det["x"] - (30 + 1.5 * (det["frame_start"] + 5.5)),
                         det["y"] - (40 + 0.5 * (det["frame_start"] + 5.5))) < 3
    assert on_target.all()                      # the one-grey-level steps are none
    # the target's local SNR is its amplitude over the quantisation's noise (about
    # 25 x 0.44 / 0.143: 77 at its peak); without the floor it was of order 1e6 and more
    assert (det["snr"] < 200).all()
    assert (out["frame_detections"]["score"] < 200).all()


def test_track_region_contrast_is_bounded_on_a_bit_exact_still_scene():
    points, tracks = track(_with_target(_still_scene()))
    assert len(tracks) == 1
    assert 0 < points["grey"].max() < 200
