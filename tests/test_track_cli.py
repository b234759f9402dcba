"""irdetect track: results file contents, options, and user errors."""

import json

import numpy as np
import pytest

from irdetect import tables
from irdetect.cli import main
from irdetect.io import read_results, write_sequence
from irdetect.metrics.mot import clear_mot
from irdetect.simulate.harbour import simulate_harbour


@pytest.fixture(scope="module")
def harbour_file(tmp_path_factory):
    frames, truth = simulate_harbour(n_frames=40, rng=3)
    path = tmp_path_factory.mktemp("seq") / "harbour.h5"
    write_sequence(path, frames, truth=truth, attrs={"frame_rate": 25.0})
    return path, truth


def test_track_writes_points_tracks_and_attrs(harbour_file, tmp_path):
    path, truth = harbour_file
    out = tmp_path / "out.h5"
    assert main(["track", str(path), "-o", str(out), "--profile", "maritime", "-q"]) == 0
    res = read_results(out)
    points, tracks = res["track_points"], res["tracks"]
    assert points.dtype == tables.TRACK_POINT and tracks.dtype == tables.TRACK
    assert len(tracks) == 3 and set(points["track_id"]) == set(tracks["track_id"])
    assert res.attrs["input"] == "harbour.h5" and res.attrs["irdetect_version"]
    assert json.loads(res.attrs["config"])["track"]["sea_sky"] is True
    r = clear_mot(truth, points, gate=5)
    assert r["mota"] > 0.9 and r["id_switches"] == 0
    # the baseline through the CLI, and the same output refused without --force
    assert main(["track", str(path), "-o", str(out), "--method", "gnn", "-q"]) == 2
    assert main(["track", str(path), "-o", str(out), "--method", "gnn", "-q", "--force"]) == 0
    assert json.loads(read_results(out).attrs["config"])["track"]["method"] == "gnn"


def test_user_errors_exit_2_without_partial_output(tmp_path, capsys):
    out = tmp_path / "x.h5"
    assert main(["track", str(tmp_path / "missing.h5"), "-o", str(out)]) == 2
    assert "error" in capsys.readouterr().err and not out.exists()
    bad = tmp_path / "bad.toml"
    bad.write_text("[track]\ngate = 'wide'\n")
    seq = tmp_path / "s.h5"
    write_sequence(seq, np.zeros((2, 20, 20), np.uint8))
    assert main(["track", str(seq), "-o", str(out), "--config", str(bad)]) == 2
    assert "track.gate must be float" in capsys.readouterr().err and not out.exists()
    # a value the tracker refuses fails before the run, as one line naming the file
    bad.write_text("[track]\nk = -3.0\n")
    assert main(["track", str(seq), "-o", str(out), "--config", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "k must be > 0" in err and "bad.toml" in err and "Traceback" not in err
    assert not out.exists()
    # two frames hold no track of three hits: said, not "no track: ... --psf 0.6"
    assert main(["track", str(seq), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "s.h5: the sequence has 2 frames; a track is confirmed after 3 hits" in err
    assert not out.exists()


def test_psf_option_sets_the_matched_filter_over_the_config(tmp_path, capsys):
    seq = tmp_path / "s.h5"
    write_sequence(seq, np.random.default_rng(0).normal(100, 5, (24, 32, 32)).astype(np.float32))
    conf = tmp_path / "c.toml"
    conf.write_text("[track]\npsf = 0.8\n")
    out = tmp_path / "t.h5"
    assert main(["track", str(seq), "-o", str(out), "--config", str(conf), "-q"]) == 0
    assert json.loads(read_results(out).attrs["config"])["track"]["psf"] == 0.8
    assert main(["track", str(seq), "-o", str(out), "--config", str(conf), "--psf", "0.6",
                 "-q", "--force"]) == 0
    assert json.loads(read_results(out).attrs["config"])["track"]["psf"] == 0.6
    capsys.readouterr()
    assert main(["track", str(seq), "-o", str(tmp_path / "u.h5"), "--psf", "-1"]) == 2
    assert capsys.readouterr().err == ("irdetect track: error: --psf -1: the PSF's sigma "
                                       "must be >= 0 px\n")
    assert not (tmp_path / "u.h5").exists()


def test_evaluate_scores_track_points(harbour_file, tmp_path, capsys):
    path, _ = harbour_file
    out = tmp_path / "t.h5"
    assert main(["track", str(path), "-o", str(out), "--profile", "maritime", "-q"]) == 0
    capsys.readouterr()
    assert main(["evaluate", str(out), "--gate", "5", "--json"]) == 0
    scores = json.loads(capsys.readouterr().out)["tracking (CLEAR-MOT)"]
    assert scores["mota"] > 0.9 and scores["id_switches"] == 0 and scores["n_targets"] == 3


@pytest.mark.parametrize("dtype, background, noise, clouds", [
    ("uint8", 60.0, 2.0, 8.0), ("uint16", 60.0, 4.0, 16.0), ("float32", 3000.0, 40.0, 0.0)])
def test_default_gates_hold_on_any_sensor(tmp_path, capsys, dtype, background, noise, clouds):
    """The same defaults find 4 blobs at SNR 8 on 8-bit, 16-bit and float scenes of any
    background and noise level (the paper's absolute grey gates found none on uint16),
    and report no false track; the configuration check prints nothing."""
    from irdetect.simulate import simulate

    frames, truth = simulate("wan2008", rng=4, dtype=dtype, background=background,
                             noise_sigma=noise, snr=8.0, psf_sigma=1.2, n_targets=4,
                             directions=(10.0, 100.0, 190.0, 280.0), speed=[0.5, 1.5],
                             n_frames=80, cloud_amplitude=clouds, margin=12.0)
    write_sequence(tmp_path / "blobs.h5", frames, truth=truth)
    assert main(["track", str(tmp_path / "blobs.h5"), "-o", str(tmp_path / "t.h5")]) == 0
    err = capsys.readouterr().err
    assert "regions" not in err          # no stray line from the dry run of the settings
    res = read_results(tmp_path / "t.h5")
    m = clear_mot(truth, res["track_points"], gate=3.0)
    assert m["mota"] >= 0.9 and m["id_switches"] <= 2, m
    assert len(res["tracks"]) == 4


def test_no_track_says_what_a_frame_by_frame_tracker_needs(tmp_path, caplog):
    """Targets at SNR 3 reach the per-frame level in too few frames for a track (the demo
    preset's are at 4): the run says so, and points to process, rather than only 0."""
    import logging

    from irdetect.simulate import simulate

    frames, truth = simulate("wan2008", rng=4, snr=3.0, n_frames=40, height=64, width=80,
                             n_targets=2)
    write_sequence(tmp_path / "dim.h5", frames, truth=truth)
    with caplog.at_level(logging.INFO, logger="irdetect"):
        assert main(["track", str(tmp_path / "dim.h5"), "-o", str(tmp_path / "t.h5")]) == 0
    said = " ".join(r.getMessage() for r in caplog.records)
    assert "0 tracks" in said and "no track: a frame-by-frame tracker" in said
    assert "irdetect process integrates 12 frames" in said and "--polarity dark" in said
    assert "--psf 0.6" in said


def test_psf_of_the_sensor_finds_what_the_default_filter_misses(tmp_path):
    """The demo preset (SNR 4, PSF sigma 0.6 px): no track with the 1-px filter, and its
    five targets followed with --psf 0.6, the sensor's own PSF."""
    from irdetect.simulate import simulate

    frames, truth = simulate("demo", rng=1)
    write_sequence(tmp_path / "demo.h5", frames, truth=truth)
    out = {}
    for psf in ("1", "0.6"):
        out[psf] = tmp_path / f"t{psf}.h5"
        assert main(["track", str(tmp_path / "demo.h5"), "-o", str(out[psf]), "--psf", psf,
                     "-q"]) == 0
    assert len(read_results(out["1"])["tracks"]) == 0
    res = read_results(out["0.6"])
    m = clear_mot(truth, res["track_points"], gate=3.0)
    assert len(res["tracks"]) == 5 and m["mota"] >= 0.75 and m["id_switches"] == 0, m


def test_paper_profile_keeps_the_papers_gates(tmp_path):
    """``--profile paper``: the absolute grey gate [100, 180] of the paper's harbour finds
    nothing on a uint16 scene of background 60 (what the defaults were before)."""
    from irdetect.simulate import simulate

    frames, truth = simulate("wan2008", rng=4, dtype="uint16", background=60.0,
                             noise_sigma=4.0, snr=8.0, psf_sigma=1.2, n_targets=4,
                             directions=(10.0, 100.0, 190.0, 280.0), n_frames=40)
    write_sequence(tmp_path / "b.h5", frames, truth=truth)
    assert main(["track", str(tmp_path / "b.h5"), "-o", str(tmp_path / "p.h5"), "-q",
                 "--profile", "paper"]) == 0
    res = read_results(tmp_path / "p.h5")
    assert len(res["tracks"]) == 0 and res.config["track"]["grey_gate"]
