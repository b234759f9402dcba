"""The sensor model is the interface of `irdetect initiate` (issue 17): parameters derived
from the measurement error and the speeds, the same tracks in any unit, no silent empty
result, /tracks per the contract."""

import json
import logging

import numpy as np
import pytest

from irdetect import tables
from irdetect.cli import main
from irdetect.errors import InputError
from irdetect.initiate import initiate_scans, scan_windows
from irdetect.initiate.sensor import SensorModel, derive_params, min_points, sensor_model
from irdetect.io import read_results
from irdetect.io.scans import read_scans, write_scans
from irdetect.metrics.initiation import score_scan_tracks
from irdetect.simulate.scans import ScanScenario, simulate_scans

#: 4 CV targets over 80 km x 80 km in metres (the issue's scene), sigma 100 m, 8 scans
TARGETS = ((10e3, 150.0, 12e3, 60.0), (60e3, -120.0, 20e3, 110.0),
           (30e3, 40.0, 70e3, -200.0), (70e3, -250.0, 65e3, -20.0))


def _scene(scale=1.0, clutter=150.0, seed=5, polar=False):
    """The scene in metres, every length divided by ``scale`` (1000: kilometres)."""
    if polar:
        s = ScanScenario(n_scans=8, period=2.0, polar=True, sigma_range=150.0,
                         sigma_azimuth=0.2, max_range=100e3, clutter_mean=clutter,
                         targets=TARGETS)
    else:
        s = ScanScenario(n_scans=8, period=2.0, region=(0.0, 80e3, 0.0, 80e3), sigma=100.0,
                         clutter_mean=clutter, targets=TARGETS)
    scans, truth, attrs = simulate_scans(s, rng=seed)
    for name in ("x", "y", "range"):
        scans[name] /= scale
    truth["x"] /= scale
    truth["y"] /= scale
    return scans, truth, attrs


def _score(tracks, truth, sigma, n_scans=8, period=2.0):
    return score_scan_tracks(tracks, truth, windows=scan_windows(truth["scan"], window=n_scans),
                             scan_times={k: k * period for k in range(n_scans)}, sigma=sigma)


@pytest.mark.parametrize("polar", [False, True])
def test_metres_and_kilometres_give_the_same_tracks(polar):
    tracks = {}
    for scale in (1.0, 1000.0):
        scans, truth, _ = _scene(scale, polar=polar)
        if polar:
            sensor = SensorModel(sigma_range=150.0 / scale, sigma_azimuth=np.radians(0.2),
                                 speed_min=20.0 / scale, speed_max=400.0 / scale)
        else:
            sensor = SensorModel(sigma=100.0 / scale, speed_min=20.0 / scale,
                                 speed_max=400.0 / scale)
        p = derive_params(sensor, scans)
        window = p.pop("window")
        tracks[scale] = initiate_scans(scans, window=window, **p)
        s = _score(tracks[scale], truth,
                   sigma=(lambda x, y: np.maximum(150.0 / scale, np.hypot(x, y) * 0.0035))
                   if polar else 100.0 / scale)
        assert s["initiated"].all() and s["n_false"].sum() == 0     # every target, no false
    m, km = tracks[1.0], tracks[1000.0]
    assert len(m) == len(km) == 4
    for name in ("rho", "x0", "y0", "vx", "vy"):
        np.testing.assert_allclose(m[name] / 1000.0, km[name], rtol=1e-6, atol=1e-9)
    for name in ("theta", "scan_start", "scan_end", "n_points", "score"):
        np.testing.assert_allclose(m[name], km[name], rtol=1e-9, atol=1e-12)


def test_derived_lengths_scale_and_counts_do_not():
    scans, _, _ = _scene(1.0)
    km = scans.copy()
    km["x"] /= 1000
    km["y"] /= 1000
    a = derive_params(SensorModel(sigma=100.0, speed_max=400.0), scans)
    b = derive_params(SensorModel(sigma=0.1, speed_max=0.4), km)
    for key in ("rho_step", "tile", "sigma", "v_max"):
        assert a[key] == pytest.approx(1000 * b[key], rel=1e-9)
    for key in ("n_theta", "min_hits", "vote_fraction", "window", "confirm_m"):
        assert a[key] == b[key]
    assert a["rho_step"] == pytest.approx(200.0) and a["tile"] > 0   # 2 sigma; tiles


def test_denser_clutter_needs_more_points():
    sparse, _, _ = _scene(clutter=20.0)
    dense, _, _ = _scene(clutter=3000.0)
    kw = dict(M=8, period=2.0, speed_max=400.0, s=100.0)
    assert min_points(sparse, **kw) == 5                 # max(4, 0.6 M)
    assert 5 < min_points(dense, **kw) <= 8


def test_sensor_model_from_options_then_attributes_and_the_message():
    s = sensor_model({"sigma": 3.0, "speed_max": 9.0}, sigma=2.0)
    assert (s.sigma, s.speed_max) == (2.0, 9.0)
    with pytest.raises(InputError, match="--sigma .* --speed MIN:MAX"):
        sensor_model({})
    with pytest.raises(InputError, match="--speed"):
        sensor_model({"sigma": 1.0})                      # no speed
    with pytest.raises(InputError, match="speed_min"):
        sensor_model({"sigma": 1.0, "speed_min": 5.0, "speed_max": 2.0})


def _write_plain(path, scale=1.0, **attrs):
    scans, truth, _ = _scene(scale)
    write_scans(path, scans, truth=truth, attrs={"period": 2.0, **attrs})


def test_cli_without_a_sensor_model_exits_2_with_the_message(tmp_path, capsys):
    p = tmp_path / "s.h5"
    _write_plain(p)
    capsys.readouterr()
    assert main(["initiate", str(p), "-o", str(tmp_path / "o.h5"), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no sensor model" in err[0] and "--speed MIN:MAX" in err[0]
    assert not (tmp_path / "o.h5").exists()
    assert main(["initiate", str(p), "-o", str(tmp_path / "o.h5"), "--sigma", "100",
                 "--speed", "fast", "-q"]) == 2


def test_cli_metres_and_km_from_options_and_from_attributes(tmp_path, capsys):
    out = {}
    for scale, unit in ((1.0, "m"), (1000.0, "km")):
        p = tmp_path / f"{unit}.h5"
        _write_plain(p, scale)
        o = tmp_path / f"{unit}.out.h5"
        assert main(["initiate", str(p), "-o", str(o), "--sigma", str(100 / scale),
                     "--speed", f"{20 / scale}:{400 / scale}", "-q"]) == 0
        out[unit] = read_results(o)["tracks"]
        # the same sensor model from the file's root attributes
        q = tmp_path / f"{unit}.attrs.h5"
        _write_plain(q, scale, sigma=100 / scale, speed_min=20 / scale, speed_max=400 / scale)
        assert main(["initiate", str(q), "-o", str(tmp_path / "a.h5"), "--force", "-q"]) == 0
        again = read_results(tmp_path / "a.h5")["tracks"]
        assert again.tobytes() == out[unit].tobytes()
        scores = json.loads(_evaluate(capsys, o))["track initiation (scans)"]
        assert scores["pt_overall"] == 1.0 and scores["n_false"] == 0
    assert len(out["m"]) == len(out["km"]) == 4
    np.testing.assert_allclose(out["m"]["x0"] / 1000, out["km"]["x0"], rtol=1e-6)


def _evaluate(capsys, path):
    capsys.readouterr()
    assert main(["evaluate", str(path), "--json"]) == 0
    return capsys.readouterr().out


def test_tracks_hold_the_scan_tracks_per_the_contract(tmp_path, capsys):
    p, o = tmp_path / "s.h5", tmp_path / "o.h5"
    _write_plain(p, sigma=100.0, speed_max=400.0)
    assert main(["initiate", str(p), "-o", str(o), "-q"]) == 0
    res = read_results(o)
    assert "scan_tracks" not in res
    tr = res["tracks"]
    for name in ("track_id", "rho", "theta", "vx", "vy", "scan_start", "scan_end",
                 "n_points", "score"):
        assert name in tr.dtype.names
    assert len(tr) == 4 and (tr["scan_end"] > tr["scan_start"]).all()
    assert ((tr["theta"] >= 0) & (tr["theta"] < np.pi)).all()
    assert res.attrs["sigma"] == 100.0 and res.attrs["speed_max"] == 400.0
    # info calls the input a scans file and the output results of initiate on scans
    capsys.readouterr()
    assert main(["info", str(p)]) == 0
    text = capsys.readouterr().out
    assert "scans file" in text and "irdetect results" not in text and "sigma 100" in text
    assert main(["info", str(o)]) == 0
    assert "results of initiate on scans" in capsys.readouterr().out
    # plot draws the scans result
    assert main(["plot", str(o), "-o", str(tmp_path / "o.png"), "-q"]) == 0
    assert (tmp_path / "o.png").stat().st_size > 1000


def test_deprecated_scan_tracks_still_scored(tmp_path, capsys, caplog):
    p, o = tmp_path / "s.h5", tmp_path / "o.h5"
    _write_plain(p, sigma=100.0, speed_max=400.0)
    assert main(["initiate", str(p), "-o", str(o), "-q"]) == 0
    import h5py
    with h5py.File(o, "a") as f:                      # a file of the previous release
        f["scan_tracks"] = f["tracks"][()]
        del f["tracks"]
    with caplog.at_level(logging.WARNING):
        scores = json.loads(_evaluate(capsys, o))["track initiation (scans)"]
    assert scores["pt_overall"] == 1.0
    assert "deprecated" in caplog.text


def test_a_run_that_finds_nothing_says_why(tmp_path, caplog):
    p, o = tmp_path / "s.h5", tmp_path / "o.h5"
    _write_plain(p, 1000.0)                           # kilometres ...
    with caplog.at_level(logging.WARNING):            # ... with a sigma of 10 cm
        assert main(["initiate", str(p), "-o", str(o), "--sigma", "0.0001", "--speed",
                     "0.02:0.4"]) == 0
    assert len(read_results(o)["tracks"]) == 0
    assert "no tracks" in caplog.text and "same units" in caplog.text


def test_presets_write_their_sensor_model():
    _, _, attrs = simulate_scans("zhang2010", rng=0, n_scans=3)
    assert (attrs["sigma"], attrs["speed_min"], attrs["speed_max"]) == (100.0, 30.0, 350.0)
    _, _, attrs = simulate_scans("liang2015", rng=0, n_scans=3)
    assert attrs["sigma_azimuth"] == pytest.approx(np.radians(0.3))
    assert (attrs["speed_min"], attrs["speed_max"]) == (100.0, 1000.0)
    assert tables.SCAN_TRACK.names[:9] == ("track_id", "rho", "theta", "vx", "vy",
                                           "scan_start", "scan_end", "n_points", "score")
