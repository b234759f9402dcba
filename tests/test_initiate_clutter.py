"""The per-track clutter test (issue 17): targets stay in sparse clutter, clutter chains go
in dense clutter, one warning past the separable limit, the false_tracks parameter from
the CLI and the config, the same tracks in any unit."""

import json
import logging

import numpy as np
import pytest

from irdetect.cli import main
from irdetect.initiate import initiate_scans, scan_windows
from irdetect.initiate.clutter import chain_expectation, hypotheses, separability
from irdetect.initiate.sensor import SensorModel, derive_params
from irdetect.io import read_results
from irdetect.io.scans import write_scans
from irdetect.metrics.initiation import score_scan_tracks
from irdetect.simulate.scans import ScanScenario, simulate_scans

#: 3 CV targets over 20 km x 20 km (metres), sigma 100 m, 8 scans 2 s apart
TARGETS = ((3e3, 150.0, 4e3, 60.0), (15e3, -120.0, 5e3, 110.0), (8e3, 40.0, 16e3, -200.0))
SENSOR = dict(sigma=100.0, speed_min=20.0, speed_max=400.0)


def _scene(clutter, targets=TARGETS, seed=3, scale=1.0):
    """Scans, truth in metres / ``scale``; ``clutter`` points per scan over the square."""
    s = ScanScenario(n_scans=8, period=2.0, region=(0.0, 20e3, 0.0, 20e3), sigma=100.0,
                     clutter_mean=clutter, targets=targets)
    scans, truth, _ = simulate_scans(s, rng=seed)
    for name in ("x", "y"):
        scans[name] /= scale
        truth[name] /= scale
    return scans, truth


def _run(scans, scale=1.0, **over):
    sensor = SensorModel(**{k: v / scale for k, v in SENSOR.items()})
    p = derive_params(sensor, scans)
    window = p.pop("window")
    p.update(over)
    return initiate_scans(scans, window=window, **p)


def _load(clutter):
    """Clutter points per 3-sigma gate per scan of the scene."""
    return clutter / 20e3 ** 2 * np.pi * 300.0 ** 2


def test_expectation_rises_with_density_and_falls_with_hits():
    s = np.full(2, 1.0)
    H = hypotheses(1e4, 18.0, 2.0, 3.0, s, s)
    hits = np.array([[3, 5, 8, 8, 8], [2, 3, 6, 8, 8]])
    lo, hi = (chain_expectation(hits, 8, c, s, s, H, 3.0) for c in (1e-3, 1e-2))
    assert (hi > lo).all()
    assert lo[0] < lo[1]                        # tighter residuals: a better chain


def test_a_true_target_stays_in_sparse_clutter():
    scans, truth = _scene(clutter=30.0)                         # load 0.02 per gate
    tracks = _run(scans)
    r = score_scan_tracks(tracks, truth, windows=scan_windows(truth["scan"], window=8),
                          scan_times={k: 2.0 * k for k in range(8)}, sigma=100.0)
    assert r["initiated"].all() and r["n_false"].sum() == 0
    # the test lets the targets through with the floor of points, not a higher global one
    assert derive_params(SensorModel(**SENSOR), scans)["min_hits"] == 5 / 8


def test_clutter_alone_gives_no_track_where_it_would_without_the_test():
    scans, _ = _scene(clutter=150.0, targets=())                # load 0.1 per gate
    without = _run(scans, false_tracks=0.0, min_hits=5 / 8)     # the floor, no test
    assert len(without) >= 1                   # the CV check alone passes clutter chains
    assert len(_run(scans)) == 0
    assert len(_run(scans, min_hits=5 / 8)) == 0               # the test, at the floor


def test_past_the_separable_limit_one_warning_and_no_tracks(caplog):
    scans, _ = _scene(clutter=700.0)                            # load 0.5 per gate
    with caplog.at_level(logging.WARNING, logger="irdetect"):
        tracks = _run(scans)
    warned = [r for r in caplog.records if "clutter too dense" in r.getMessage()]
    assert len(warned) == 1 and warned[0].exc_info is None
    load, limit = separability(scans["x"], scans["y"], scans["time"], 8,
                               {**derive_params(SensorModel(**SENSOR), scans),
                                "sigma_range": 0.0, "sigma_azimuth": 0.0})
    assert load > limit and f"{load:.3g} clutter points per 3-sigma gate" in \
        warned[0].getMessage()
    assert abs(load - _load(700.0)) < 0.15 * _load(700.0)        # measured, not given
    assert len(tracks) == 0


def test_no_warning_in_sparse_clutter(caplog):
    scans, _ = _scene(clutter=30.0)
    with caplog.at_level(logging.WARNING, logger="irdetect"):
        _run(scans)
    assert "clutter too dense" not in caplog.text


def test_metres_and_kilometres_give_the_same_tracks():
    out = {}
    for scale in (1.0, 1000.0):
        scans, _ = _scene(clutter=100.0, scale=scale)
        out[scale] = _run(scans, scale=scale)
    m, km = out[1.0], out[1000.0]
    assert len(m) == len(km) == 3
    for name in ("rho", "x0", "y0", "vx", "vy"):
        np.testing.assert_allclose(m[name] / 1000.0, km[name], rtol=1e-6, atol=1e-9)
    np.testing.assert_array_equal(m["n_points"], km["n_points"])


def _write(path, clutter=30.0):
    scans, truth = _scene(clutter)
    write_scans(path, scans, truth=truth, attrs={"period": 2.0, **SENSOR})


def _config(out):
    return json.loads(read_results(out).attrs["config"])["initiate"]


def test_false_tracks_from_the_cli_and_the_config(tmp_path):
    p, o = tmp_path / "s.h5", tmp_path / "o.h5"
    _write(p)
    assert main(["initiate", str(p), "-o", str(o), "-q"]) == 0
    assert _config(o)["false_tracks"] == 0.05                   # the default
    assert main(["initiate", str(p), "-o", str(o), "--force", "-q",
                 "--false-tracks", "0.2"]) == 0
    assert _config(o)["false_tracks"] == 0.2
    cfg = tmp_path / "c.toml"
    cfg.write_text("[initiate]\nfalse_tracks = 0.01\n")
    assert main(["initiate", str(p), "-o", str(o), "--force", "-q", "--config",
                 str(cfg)]) == 0
    assert _config(o)["false_tracks"] == 0.01
    assert main(["initiate", str(p), "-o", str(o), "--force", "-q", "--config", str(cfg),
                 "--false-tracks", "0"]) == 0
    assert _config(o)["false_tracks"] == 0.0                    # the option wins


@pytest.mark.parametrize("how", ["option", "config"])
def test_a_negative_false_tracks_exits_2_naming_it(tmp_path, capsys, how):
    p, o = tmp_path / "s.h5", tmp_path / "o.h5"
    _write(p)
    cfg = tmp_path / "c.toml"
    cfg.write_text("[initiate]\nfalse_tracks = -1.0\n")
    extra = ["--false-tracks", "-1"] if how == "option" else ["--config", str(cfg)]
    capsys.readouterr()
    assert main(["initiate", str(p), "-o", str(o), "-q"] + extra) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "false" in err[0] and "Traceback" not in err[0]
    assert (str(p) if how == "option" else str(cfg)) in err[0]
