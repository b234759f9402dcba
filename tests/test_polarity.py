"""Dark targets (a black-hot recording, a cold target): ``suppress.polarity = "dark"``
mirrors the frames in grey level, so a black-hot sequence gives the white-hot one's
results, and the default (bright) misses its targets."""

import dataclasses
import json

import numpy as np
import pytest

from irdetect.cli import main
from irdetect.config import ProcessConfig
from irdetect.io import read_results, write_sequence
from irdetect.metrics.detection import score_detections
from irdetect.pipeline import detect_sequence
from irdetect.simulate import simulate
from irdetect.suppress import bright_up, suppress
from irdetect.track import track

DARK = ProcessConfig(suppress=dataclasses.replace(ProcessConfig().suppress, polarity="dark"))


@pytest.fixture(scope="module")
def panned():
    """A uint8 sequence of 5 targets under a camera panning 1.5 px/frame."""
    return simulate("wan2008", snr=5, rng=2, camera_pan=(1.5, 0.5), n_frames=48)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.int16, np.int32])
def test_bright_up_of_integers_is_exact_in_range_and_its_own_inverse(dtype):
    info = np.iinfo(dtype)
    a = np.unique(np.array([info.min, info.min + 1, 0, info.max - 1, info.max], dtype))
    b = bright_up(a)
    assert b.dtype == dtype
    assert b[0] == info.max and b[-1] == info.min          # the order reversed, in range
    assert np.all(np.diff(b.astype(np.int64)) <= 0)
    assert np.array_equal(bright_up(b), a)


def test_bright_up_negates_floats():
    f = np.array([[-1.5, 0.0, 2.0]], np.float32)
    assert bright_up(f).dtype == np.float32 and np.array_equal(bright_up(f), -f)


@pytest.mark.parametrize("method", ["tophat", "temporal", "registered", "auto"])
def test_dark_on_the_mirrored_frames_is_bright_on_the_frames(panned, method):
    frames, truth = panned
    previous, block, following = frames[:20], frames[20:32], frames[32:]
    want = suppress(block, previous, following, method=method)
    got = suppress(bright_up(block), bright_up(previous), bright_up(following),
                   method=method, polarity="dark")
    assert np.array_equal(got, want)
    # as bright, the mirrored frames' targets are dark: the residual at them is not
    # positive (the top-hat's is clipped at 0), as bright it stands out
    plain = suppress(bright_up(block), bright_up(previous), bright_up(following),
                     method=method)
    t = truth[(truth["frame"] >= 20) & (truth["frame"] < 32)]
    x, y = np.rint(t["x"]).astype(int), np.rint(t["y"]).astype(int)
    inside = (x >= 0) & (x < frames.shape[2]) & (y >= 0) & (y < frames.shape[1])
    at = (t["frame"][inside] - 20, y[inside], x[inside])
    assert want[at].mean() > 0.5 * t["amplitude"].mean() and plain[at].mean() <= 1.0


def test_unknown_polarity_is_refused():
    with pytest.raises(ValueError, match="polarity must be one of"):
        suppress(np.zeros((16, 16), np.float32), method="tophat", polarity="cold")


def _pd(out, truth, frames):
    return score_detections(out["detections"], truth, n_frames=len(frames), length=12,
                            step=12, gate=3.0, shape=frames.shape[1:])["pd"]


def test_process_finds_the_dark_targets_of_a_black_hot_sequence(panned):
    frames, truth = panned
    white = detect_sequence(frames)
    black = bright_up(frames)
    dark = detect_sequence(black, DARK)
    assert _pd(white, truth, frames) == 1.0
    # the same detections: only the camera's offsets, measured on the black-hot frames,
    # differ in the last digits
    a, b = white["detections"], dark["detections"]
    assert len(a) == len(b) and len(white["tracks"]) == len(dark["tracks"])
    np.testing.assert_allclose(b["x"], a["x"], atol=1e-3)
    np.testing.assert_allclose(b["y"], a["y"], atol=1e-3)
    # the default (bright) on the black-hot frames misses most target-windows
    assert _pd(detect_sequence(black), truth, frames) < 0.5


def test_track_follows_the_dark_targets():
    frames, truth = simulate("wan2008", snr=7, n_targets=1, n_frames=40, rng=1)
    points, tracks = track(frames)
    dark_points, dark_tracks = track(bright_up(frames), suppression={"polarity": "dark"})
    assert len(tracks) == len(dark_tracks) == 1
    np.testing.assert_allclose(dark_points["x"], points["x"], atol=1e-3)
    # the top-hat regions (the maritime and paper profiles) are mirrored too
    p1, t1 = track(frames, regions="tophat", false_tracks=0.0, confirm_window=5)
    p2, t2 = track(bright_up(frames), regions="tophat", suppression={"polarity": "dark"},
                   false_tracks=0.0, confirm_window=5)
    assert len(t1) == len(t2) >= 1 and np.array_equal(p1["x"], p2["x"])


def test_cli_polarity_is_stored_and_named(tmp_path, capsys):
    frames, truth = simulate("wan2008", snr=6, n_targets=1, n_frames=40, rng=1)
    seq = tmp_path / "black.h5"
    write_sequence(seq, bright_up(frames), truth=truth)
    out = tmp_path / "out.h5"
    assert main(["process", str(seq), "-o", str(out), "--polarity", "dark", "-q"]) == 0
    res = read_results(out)
    assert json.loads(res.attrs["config"])["suppress"]["polarity"] == "dark"
    assert len(res["tracks"]) == 1
    capsys.readouterr()
    assert main(["info", str(out)]) == 0
    assert 'suppress.polarity = "dark"' in capsys.readouterr().out
    tout = tmp_path / "track.h5"
    assert main(["track", str(seq), "-o", str(tout), "--polarity", "dark", "-q"]) == 0
    assert len(read_results(tout)["tracks"]) == 1
    # a value other than bright or dark: argparse's one line, exit 2
    with pytest.raises(SystemExit) as exc:
        main(["process", str(seq), "-o", str(tmp_path / "x.h5"), "--polarity", "cold"])
    assert exc.value.code == 2 and not (tmp_path / "x.h5").exists()


def test_process_that_detects_nothing_names_the_option(tmp_path, caplog):
    import logging

    rng = np.random.default_rng(0)
    seq = tmp_path / "noise.h5"
    write_sequence(seq, rng.normal(100, 2, (40, 64, 64)).astype(np.float32))
    with caplog.at_level(logging.INFO, logger="irdetect"):
        assert main(["process", str(seq), "-o", str(tmp_path / "out.h5")]) == 0
    said = " ".join(r.getMessage() for r in caplog.records)
    assert "0 detections" in said and "--polarity dark" in said
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="irdetect"):
        assert main(["process", str(seq), "-o", str(tmp_path / "dark.h5"),
                     "--polarity", "dark"]) == 0
    assert "--polarity dark" not in " ".join(r.getMessage() for r in caplog.records)


def test_a_real_recording_saved_black_hot():
    """istd640-seq4-71 (a 4.6 px/frame pan over a city) saved as 255 - v: the defaults
    lose its target, ``dark`` finds the recording's detections and track again."""
    from tests.conftest import real_sequence

    from irdetect.io import open_sequence

    with open_sequence(real_sequence("istd640-seq4-71") / "frames") as src:
        frames = src[0:len(src)]
    black = bright_up(frames)
    assert black.dtype == np.uint8 and np.array_equal(black, 255 - frames)
    white, dark = detect_sequence(frames), detect_sequence(black, DARK)
    a, b = white["detections"], dark["detections"]
    assert len(a) == len(b) and len(white["tracks"]) == len(dark["tracks"]) == 1
    np.testing.assert_allclose(b["x"], a["x"], atol=1e-3)
    np.testing.assert_allclose(b["y"], a["y"], atol=1e-3)
    assert len(detect_sequence(black)["tracks"]) == 0


@pytest.mark.parametrize("command", ["process", "track"])
def test_a_run_on_constant_frames_says_so(tmp_path, caplog, command):
    """A dataset of zeros (the wrong one of a file) finds nothing: the run says the frames
    hold one value, not that the targets may be dark."""
    import logging

    seq = tmp_path / "zeros.h5"
    write_sequence(seq, np.zeros((40, 64, 64), np.uint16))
    with caplog.at_level(logging.INFO, logger="irdetect"):
        assert main([command, str(seq), "-o", str(tmp_path / "out.h5")]) == 0
    said = " ".join(r.getMessage() for r in caplog.records)
    assert "frames 0, 20, 39 each hold a single value (0)" in said and "--dataset" in said
    assert "--polarity dark" not in said
