import numpy as np
import pytest

from irdetect import tables
from irdetect.cli import main
from irdetect.errors import InputError
from irdetect.io import read_results
from irdetect.io.scans import read_scans, write_scans
from irdetect.metrics.initiation import score_scan_tracks
from irdetect.simulate.scans import simulate_scans


def test_liang2015_scenario_runs_from_the_cli(tmp_path):
    scans, out = tmp_path / "s.h5", tmp_path / "o.h5"
    assert main(["simulate-scans", str(scans), "--scenario", "liang2015", "--seed", "2",
                 "-q"]) == 0
    assert main(["initiate", str(scans), "-o", str(out), "--window", "5", "-q"]) == 0
    res = read_results(out)
    tracks = res["tracks"]
    s, truth, attrs = read_scans(scans)
    assert np.isfinite(s["range"]).all()                      # polar columns kept
    times = {int(k): float(k) * attrs["period"] for k in np.unique(truth["scan"])}
    sc = score_scan_tracks(tracks, truth, windows=[(0, 4)], scan_times=times,
                           sigma=lambda x, y: np.maximum(200.0, np.hypot(x, y) * 0.00524))
    assert sc["initiated"].sum() >= 4 and sc["n_false"].sum() <= 1
    assert main(["initiate", str(scans), "-o", str(out), "-q"]) == 2       # exists, no --force


def test_zhang2010_hough_sc_from_the_cli(tmp_path):
    scans, out = tmp_path / "z.h5", tmp_path / "zo.h5"
    assert main(["simulate-scans", str(scans), "--scenario", "zhang2010", "--seed", "1",
                 "--clutter-density", "0.03", "-q"]) == 0
    assert main(["initiate", str(scans), "-o", str(out), "--method", "hough-sc",
                 "--window", "10", "-q"]) == 0
    tracks = read_results(out)["tracks"]
    _, truth, _ = read_scans(scans)
    sc = score_scan_tracks(tracks, truth, windows=[(0, 9)], scan_times={k: float(k) for k in
                           range(10)}, sigma=100.0)
    assert sc["initiated"].all() and sc["n_false"].sum() == 0
    assert np.median(sc["speed_error"]) < 0.1


def _write(path, rows, **attrs):
    write_scans(path, tables.from_columns(tables.SCAN, **rows), attrs=attrs)


def test_bad_scans_files(tmp_path):
    p = tmp_path / "a.h5"
    _write(p, dict(scan=[1, 0, 1], time=[1.0, 0.0, 1.0], x=[1.0, 2.0, 3.0], y=[0.0, 0.0, 0.0]))
    s, _, _ = read_scans(p)                                   # out of order: sorted
    assert s["scan"].tolist() == [0, 1, 1]
    p = tmp_path / "b.h5"
    _write(p, dict(scan=[0, 1], time=[5.0, 1.0], x=[1.0, 2.0], y=[0.0, 0.0]))
    with pytest.raises(InputError, match="disagree"):
        read_scans(p)
    p = tmp_path / "c.h5"
    _write(p, dict(scan=[0, 1], time=[0.0, 1.0], x=[np.nan, 2.0], y=[0.0, 0.0]))
    with pytest.raises(InputError, match="NaN"):
        read_scans(p)
    p = tmp_path / "d.h5"
    _write(p, dict(scan=[0, 1, 1], time=[0.0, 1.0, 1.0], x=[10.0, 20.0, 5e5], y=[0.0, 0.0, 0.0],
                   range=[10.0, 20.0, 5e5], azimuth=[0.0, 0.0, 0.0]), max_range=1000.0)
    s, _, _ = read_scans(p)                                   # beyond radar range: dropped
    assert len(s) == 2


def test_empty_scan_and_single_scan(tmp_path):
    scans, truth, _ = simulate_scans("liang2015", rng=3)
    gap = scans[scans["scan"] != 2]                            # scan 2 empty
    from irdetect.initiate import initiate_scans
    tr = initiate_scans(gap, window=5, method="fuzzy-parallel-hough", rho_step=500.0,
                        n_theta=200, sigma=200.0, min_hits=0.6, v_min=100.0, v_max=1000.0)
    assert tr.dtype == tables.SCAN_TRACK          # parallel rule: no cell has all scans
    one = initiate_scans(scans[scans["scan"] == 0], window=5)
    assert len(one) == 0 and one.dtype == tables.SCAN_TRACK
