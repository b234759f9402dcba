"""Binning of oversampled footage (``suppress.bin``, ``irdetect.binning``)."""

import dataclasses

import numpy as np
import pytest

from irdetect import tables
from irdetect.binning import Binned, binned_mask, to_binned, to_input
from irdetect.cli import main
from irdetect.config import ProcessConfig
from irdetect.io import read_results
from irdetect.pipeline import detect_sequence
from irdetect.simulate import simulate
from irdetect.track import track


def _replicated(frames: np.ndarray, factor: int) -> np.ndarray:
    """Each pixel a factor x factor block of its value: the footage oversampled."""
    return np.repeat(np.repeat(frames, factor, axis=1), factor, axis=2)


def _with_bin(factor: int) -> ProcessConfig:
    cfg = ProcessConfig()
    return dataclasses.replace(cfg, suppress=dataclasses.replace(cfg.suppress, bin=factor))


def test_blocks_are_averaged_and_the_remainder_dropped():
    frames = np.arange(3 * 5 * 7, dtype=np.uint16).reshape(3, 5, 7)
    b = Binned(frames, 2)
    assert b.shape == (3, 2, 3) and b.dtype == np.float32 and len(b) == 3
    want = frames[:, :4, :6].reshape(3, 2, 2, 3, 2).mean(axis=(2, 4))
    np.testing.assert_allclose(b[0:3], want)
    np.testing.assert_allclose(b[-1], want[2])
    with pytest.raises(ValueError, match="suppress.bin must be an integer from 1 to 16"):
        Binned(frames, 0)


def test_a_block_with_an_excluded_pixel_is_excluded():
    mask = np.zeros((5, 6), bool)
    mask[3, 1] = True
    got = binned_mask(mask, 2)
    assert got.shape == (2, 3) and got.sum() == 1 and got[1, 0]
    assert binned_mask(None, 2) is None


@pytest.mark.parametrize("name", ["detections", "segments", "tracks", "frame_tracks",
                                  "track_points", "camera"])
def test_tables_go_to_the_input_pixels_and_back(name):
    rng = np.random.default_rng(0)
    rows = np.zeros(4, tables.BY_NAME[name])
    for field in rows.dtype.names:
        if rows.dtype[field].kind == "f":
            rows[field] = rng.uniform(0.5, 3.0, 4)
    full = to_input(name, rows, 3)
    back = to_binned(name, full, 3)
    for field in rows.dtype.names:
        np.testing.assert_allclose(back[field], rows[field], err_msg=field)
    if "x" in rows.dtype.names:       # pixel i holds the input's 3i .. 3i + 2: centre 3i + 1
        np.testing.assert_allclose(full["x"], 3 * rows["x"] + 1)
    if name == "tracks":              # the line still passes through the moved point
        t = full["theta"]
        np.testing.assert_allclose(full["x0"] * np.cos(t) + full["y0"] * np.sin(t),
                                   full["rho"] + 3 * (rows["x0"] * np.cos(t) + rows["y0"]
                                                      * np.sin(t) - rows["rho"]))
    assert to_input(name, rows, 1) is rows


def test_binned_replicated_footage_gives_the_originals_results_in_its_pixels():
    frames, truth = simulate("wan2008", snr=6, n_targets=2, n_frames=48, height=96,
                             width=128, camera_pan=(0.5, 0.25), rng=3)
    frames = frames.astype(np.float32)     # the original, as the binned frames hold it
    base = detect_sequence(frames)
    got = detect_sequence(_replicated(frames, 2), _with_bin(2))
    assert len(base["detections"]) >= 8 and len(base["tracks"]) == 2
    for name in ("detections", "tracks", "frame_detections", "camera", "segments"):
        assert len(got[name]) == len(base[name]), name
        want = to_input(name, base[name], 2)
        for field in want.dtype.names:
            np.testing.assert_allclose(got[name][field], want[field], atol=1e-6,
                                       err_msg=f"{name}.{field}")


def test_the_tracker_bins_too():
    frames, truth = simulate("wan2008", snr=8, n_targets=1, n_frames=40, height=96,
                             width=128, rng=1)
    frames = frames.astype(np.float32)
    points, summary = track(frames)
    got_points, got_summary = track(_replicated(frames, 2), suppression={"bin": 2})
    assert len(summary) == 1 and len(got_summary) == 1
    want = to_input("track_points", points, 2)
    np.testing.assert_allclose(got_points["x"], want["x"], atol=1e-6)
    np.testing.assert_allclose(got_points["area"], 4 * points["area"])
    np.testing.assert_allclose(got_summary["x0"], 2 * summary["x0"] + 0.5, atol=1e-6)


def test_the_cli_bins_and_writes_the_inputs_pixels(tmp_path):
    frames, truth = simulate("wan2008", snr=8, n_targets=1, n_frames=48, height=64,
                             width=80, rng=2)
    big = _replicated(frames, 2)
    np.save(tmp_path / "big.npy", big)
    out = tmp_path / "big.irdetect.h5"
    assert main(["process", str(tmp_path / "big.npy"), "-o", str(out), "--bin", "2", "-q"]) == 0
    res = read_results(out)
    assert res.attrs["frame_width"] == 160 and '"bin": 2' in res.attrs["config"]
    det = res["detections"]
    assert len(det)
    path = truth[truth["frame"] == (det["frame_start"][0] + det["frame_end"][0]) // 2]
    assert np.hypot(det["x"][0] - (2 * path["x"][0] + 0.5),
                    det["y"][0] - (2 * path["y"][0] + 0.5)).min() < 4


@pytest.mark.parametrize("command", ["process", "track"])
def test_a_bin_out_of_range_or_too_coarse_is_refused(tmp_path, capsys, command):
    frames, _ = simulate("wan2008", n_frames=36, height=64, width=64, rng=0)
    np.save(tmp_path / "s.npy", frames)
    for value, message in (("0", "suppress.bin must be an integer from 1 to 16"),
                           ("16", "binned 16x16 (suppress.bin) are too small")):
        assert main([command, str(tmp_path / "s.npy"), "-o", str(tmp_path / "o.h5"),
                     "--bin", value]) == 2
        err = capsys.readouterr().err
        assert message in err and "Traceback" not in err and len(err.splitlines()) == 1
    assert not (tmp_path / "o.h5").exists()
