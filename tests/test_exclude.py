"""Excluded pixels (``irdetect.exclude``): a burned-in overlay whose digits change every
frame is reported nowhere once its pixels are excluded, and the targets stay found."""

import json

import cv2
import numpy as np
import pytest

from irdetect.cli import main
from irdetect.config import ProcessConfig
from irdetect.errors import InputError
from irdetect.exclude import excluded, exclusion_mask, read_exclusions
from irdetect.io import read_results, write_sequence
from irdetect.pipeline import detect_sequence
from irdetect.simulate import simulate
from irdetect.track import track

#: the overlay's box (x0, y0, x1, y1) in the 320 x 240 frames of ``overlaid``
BOX = "0,215,140,240"


@pytest.fixture(scope="module")
def overlaid():
    """5 targets at SNR 6 under a time stamp burned into the bottom left corner, its
    digits changing every frame (white, anti-aliased, as a gimbal's video shows it)."""
    frames, truth = simulate("wan2008", snr=6, rng=3, n_frames=48)
    frames = frames.copy()
    for k, f in enumerate(frames):
        cv2.putText(f, f"{k:04d} {3 * k % 97:02d}", (4, 232), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                    255, 1, cv2.LINE_AA)
    return frames, truth


def test_rectangles_and_mask_images(tmp_path):
    mask = exclusion_mask(["-5,-5,3,2", "8,6,100,100"], (10, 12))
    assert mask.shape == (10, 12) and mask.sum() == 3 * 2 + 4 * 4
    assert mask[0:2, 0:3].all() and mask[6:, 8:].all() and not mask[2:6].any()
    image = np.zeros((10, 12), np.uint8)
    image[4, 5] = 255
    cv2.imwrite(str(tmp_path / "m.png"), image)
    both = exclusion_mask([str(tmp_path / "m.png"), "0,0,1,1"], (10, 12))
    assert both.sum() == 2 and both[4, 5] and both[0, 0]
    assert exclusion_mask([], (10, 12)) is None
    # a point is judged by its nearest pixel; points off the frame are not excluded
    assert excluded(both, [5.4, 4.6, 5.6, -1.0, 30.0], [4.4, 3.6, 4.0, 0.0, 0.0]).tolist() == [
        True, True, False, False, False]
    assert excluded(None, [1.0], [1.0]).tolist() == [False]


@pytest.mark.parametrize("spec, message", [("10,10,5,20", "is empty"),
                                           ("1,2,3", "a rectangle is X0,Y0,X1,Y1"),
                                           ("nowhere.png", "not found")])
def test_bad_entries_are_refused(spec, message):
    with pytest.raises(InputError, match=message):
        read_exclusions([spec])


def test_a_mask_image_of_another_size_is_refused(tmp_path):
    cv2.imwrite(str(tmp_path / "m.png"), np.zeros((8, 8), np.uint8))
    with pytest.raises(InputError, match="exclusion mask of 8x8 px for frames of 12x10"):
        exclusion_mask([str(tmp_path / "m.png")], (10, 12))


def test_process_reports_nothing_in_the_excluded_pixels(overlaid):
    frames, truth = overlaid
    box = exclusion_mask([BOX], frames.shape[1:])
    plain = detect_sequence(frames)
    clean = detect_sequence(frames, ProcessConfig(exclude=(BOX,)))
    for out, n_in in ((plain, None), (clean, 0)):
        inside = [excluded(box, out[t]["x"], out[t]["y"]).sum()
                  for t in ("detections", "frame_detections")]
        if n_in is None:         # the overlay's changing digits are peaks and a detection
            assert inside[0] >= 1 and inside[1] >= 50
        else:
            assert inside == [0, 0]
    # the targets: the same 5 tracks as without the overlay
    assert len(clean["tracks"]) == len(detect_sequence(simulate(
        "wan2008", snr=6, rng=3, n_frames=48)[0])["tracks"]) == 5


def test_track_takes_no_region_in_the_excluded_pixels(overlaid):
    frames, _ = overlaid
    box = exclusion_mask([BOX], frames.shape[1:])
    points, tracks = track(frames, exclude=(BOX,))
    assert len(tracks) == 5 and not excluded(box, points["x"], points["y"]).any()
    points, tracks = track(frames, regions="tophat", false_tracks=0.0, exclude=(BOX,))
    assert not excluded(box, points["x"], points["y"]).any()


def test_cli_exclude_is_stored_and_bad_masks_exit_2(overlaid, tmp_path, capsys):
    frames, truth = overlaid
    seq = tmp_path / "osd.h5"
    write_sequence(seq, frames, truth=truth)
    out = tmp_path / "out.h5"
    assert main(["process", str(seq), "-o", str(out), "--exclude", BOX, "-q"]) == 0
    res = read_results(out)
    assert json.loads(res.attrs["config"])["exclude"] == [BOX]
    box = exclusion_mask([BOX], frames.shape[1:])
    assert not excluded(box, res["detections"]["x"], res["detections"]["y"]).any()
    capsys.readouterr()
    assert main(["info", str(out)]) == 0
    assert f'exclude = ["{BOX}"]' in capsys.readouterr().out
    tout = tmp_path / "track.h5"
    assert main(["track", str(seq), "-o", str(tout), "--exclude", BOX, "-q"]) == 0
    assert json.loads(read_results(tout).attrs["config"])["exclude"] == [BOX]
    # a mask image of another size, and a bad rectangle: one line, exit 2, no output
    cv2.imwrite(str(tmp_path / "small.png"), np.full((8, 8), 255, np.uint8))
    for cmd in ("process", "track"):
        for spec in (str(tmp_path / "small.png"), "3,3,1,1"):
            bad = tmp_path / f"bad-{cmd}.h5"
            assert main([cmd, str(seq), "-o", str(bad), "--exclude", spec, "-q"]) == 2
            err = capsys.readouterr().err
            assert err.count("\n") == 1 and "Traceback" not in err and not bad.exists()


def test_the_excluded_pixels_are_no_clutter_sample_of_the_operating_level(overlaid):
    """The overlay's changing digits are the brightest residue of the combined-frame
    path's integrated map; with their pixels excluded, its operating level is the clean
    scene's again (and the combined path's detections come back)."""
    frames, _ = overlaid
    clean = detect_sequence(simulate("wan2008", snr=6, rng=3, n_frames=48)[0])["detections"]
    excl = detect_sequence(frames, ProcessConfig(exclude=(BOX,)))["detections"]
    # window by window: each window's level is its own map's tail fit
    want = {k: v for k, v in zip(clean["combined_frame"], clean["level"]) if np.isfinite(v)}
    got = {k: v for k, v in zip(excl["combined_frame"], excl["level"]) if np.isfinite(v)}
    assert len(got) >= 2 and set(got) == set(want)
    assert all(abs(got[k] - want[k]) <= 0.1 * want[k] for k in got), (got, want)
