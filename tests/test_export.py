"""`irdetect export` (CSV, MOTChallenge text, JSON) and `irdetect.read_results`: a MOT
file round-trips through py-motmetrics and scores against a MOT truth file of the
simulated targets; the tables come back as DataFrames when pandas is installed."""

from __future__ import annotations

import builtins
import csv
import json
import os

import numpy as np
import pytest

import irdetect
from irdetect.cli import main
from irdetect.export import MOT_BOX, mot_rows, track_positions
from irdetect.io import ResultsWriter, read_results, write_sequence
from irdetect.simulate import simulate


@pytest.fixture(scope="module")
def processed(tmp_path_factory):
    """A processed simulated sequence (5 targets, SNR 6): (folder, truth)."""
    folder = tmp_path_factory.mktemp("export")
    frames, truth = simulate("wan2008", rng=1, n_frames=48, height=96, width=96, snr=6.0)
    write_sequence(folder / "seq.h5", frames, truth=truth)
    assert main(["process", str(folder / "seq.h5"), "-o", str(folder / "res.h5"), "-q"]) == 0
    return folder, truth


def _truth_mot(truth, path, box=MOT_BOX):
    """The simulator's truth as a MOT file (the same boxes, frames from 1)."""
    rows = np.zeros(len(truth), [("frame", "<i8"), ("track_id", "<i8"), ("x", "<f8"),
                                 ("y", "<f8"), ("score", "<f8")])
    rows["frame"], rows["track_id"] = truth["frame"], truth["target"]
    rows["x"], rows["y"], rows["score"] = truth["x"], truth["y"], 1.0
    np.savetxt(path, mot_rows(rows, box=box), delimiter=",", fmt="%.4f")


# py-motmetrics' own reader, under pandas 3, warns about its use of pandas
@pytest.mark.filterwarnings("ignore:Operation with tuple is deprecated")
def test_mot_file_round_trips_through_motmetrics(processed, cli):
    import motmetrics as mm

    folder, truth = processed
    code, _, err = cli("export", folder / "res.h5", "--format", "mot", "-o", "mot")
    assert code == 0, err
    dt = mm.io.loadtxt("mot/tracks_mot.txt", fmt="mot15-2D", min_confidence=-1)
    positions = track_positions(read_results(folder / "res.h5"))
    assert len(dt) == len(positions) > 0
    # the boxes' centres are the track positions: the file counts pixels from 1, as MOT
    # does, and motmetrics' reader takes 1 off again
    dt_sorted = dt.sort_index()
    np.testing.assert_allclose((dt_sorted["X"] + dt_sorted["Width"] / 2).to_numpy(),
                               positions["x"], atol=2e-3)
    np.testing.assert_allclose((dt_sorted["Y"] + dt_sorted["Height"] / 2).to_numpy(),
                               positions["y"], atol=2e-3)
    assert dt.index.get_level_values("FrameId").min() >= 1
    _truth_mot(truth, "gt.txt")
    gt = mm.io.loadtxt("gt.txt", fmt="mot15-2D", min_confidence=-1)
    # centre distance within 3 px (evaluate's gate): a point target's box is a convention,
    # and motmetrics 1.4's IoU calls np.asfarray, gone in numpy 2
    acc = mm.utils.compare_to_groundtruth(gt, dt, "euc", distfields=["X", "Y"], distth=3.0)
    summary = mm.metrics.create().compute(acc, metrics=["mota", "num_false_positives",
                                                        "num_switches"], name="x")
    # evaluate scores 4 of the 5 targets initiated over the whole sequence, no false
    # track: MOTA is about 4/5, with no false positives and no id switches to speak of
    mota = float(summary["mota"].iloc[0])
    assert 0.7 <= mota <= 1.0, summary
    assert int(summary["num_false_positives"].iloc[0]) <= 0.05 * len(dt)
    assert int(summary["num_switches"].iloc[0]) == 0


def test_csv_and_json_hold_every_table(processed, cli, tmp_path):
    folder, _ = processed
    old = os.umask(0o022)
    try:
        for fmt in ("csv", "json"):
            code, _, err = cli("export", folder / "res.h5", "--format", fmt, "-o", "out")
            assert code == 0, err
    finally:
        os.umask(old)
    res = read_results(folder / "res.h5")
    with open(tmp_path / "out" / "tracks.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == len(res["tracks"]) and set(rows[0]) == set(res["tracks"].dtype.names)
    with open(tmp_path / "out" / "detections.csv", newline="") as fh:
        assert sum(1 for _ in fh) == len(res["detections"]) + 1
    positions = np.genfromtxt(tmp_path / "out" / "track_positions.csv", delimiter=",",
                              names=True)
    span = res["tracks"]["frame_end"] - res["tracks"]["frame_start"] + 1
    assert len(positions) == span.sum()
    doc = json.loads((tmp_path / "out" / "results.json").read_text())
    assert len(doc["tables"]["detections"]) == len(res["detections"])
    assert doc["attrs"]["input"] == "seq.h5" and "combine" in doc["config"]
    for name in os.listdir(tmp_path / "out"):
        assert (tmp_path / "out" / name).stat().st_mode & 0o777 == 0o644, name
    # an existing file is kept without --force, and nothing else is written
    before = (tmp_path / "out" / "tracks.csv").read_bytes()
    code, _, err = cli("export", folder / "res.h5", "--format", "csv", "-o", "out")
    assert code == 2 and "--force" in err and len(err.strip().splitlines()) == 1
    code, _, err = cli("export", folder / "res.h5", "--format", "csv", "-o", "out", "--force")
    assert code == 0 and (tmp_path / "out" / "tracks.csv").read_bytes() == before
    assert not [n for n in os.listdir(tmp_path / "out") if n.startswith(".")]
    code, _, err = cli("export", "missing.h5", "--format", "csv", "-o", "out2")
    assert code == 2 and "missing.h5" in err and not (tmp_path / "out2").exists()
    from irdetect import tables
    for name, table in (("tracks", tables.empty(tables.SCAN_TRACK)),    # irdetect initiate's
                        ("scan_tracks", np.zeros(0, [("track_id", "<i8"), ("x", "<f8")]))):
        with ResultsWriter(tmp_path / f"{name}.h5") as out:
            out.write(name, table)
        code, _, err = cli("export", f"{name}.h5", "--format", "mot", "-o", "out3")
        assert code == 2 and "--format json or mat" in err and not (tmp_path / "out3").exists()


def test_scan_tracks_of_initiate_go_out_as_json_and_mat(cli, tmp_path):
    from scipy.io import loadmat

    assert cli("simulate-scans", "scans.h5", "--seed", "1", "-q")[0] == 0
    assert cli("initiate", "scans.h5", "-o", "r.h5", "-q")[0] == 0
    tracks = read_results(tmp_path / "r.h5")["tracks"]
    assert len(tracks) and "scan_start" in tracks.dtype.names
    for fmt in ("json", "mat"):
        code, _, err = cli("export", "r.h5", "--format", fmt, "-o", "out")
        assert code == 0, err
    doc = json.loads((tmp_path / "out" / "results.json").read_text())
    assert len(doc["tables"]["tracks"]) == len(tracks) and doc["track_positions"] == []
    mat = loadmat(tmp_path / "out" / "results.mat", squeeze_me=True, struct_as_record=False)
    np.testing.assert_array_equal(np.atleast_1d(mat["tracks"].scan_start), tracks["scan_start"])


def test_mat_holds_every_table_as_matlab_structs(processed, cli, tmp_path):
    from scipy.io import loadmat

    folder, _ = processed
    code, _, err = cli("export", folder / "res.h5", "--format", "mat", "-o", "out")
    assert code == 0, err
    res = read_results(folder / "res.h5")
    mat = loadmat(tmp_path / "out" / "results.mat", squeeze_me=True, struct_as_record=False)
    for name, table in res.tables.items():
        got = mat[name]
        for field in table.dtype.names:
            np.testing.assert_array_equal(np.atleast_1d(getattr(got, field)), table[field],
                                          err_msg=f"{name}.{field}")
    span = res["tracks"]["frame_end"] - res["tracks"]["frame_start"] + 1
    assert np.atleast_1d(mat["track_positions"].x).size == span.sum()
    assert mat["attrs"].input == "seq.h5" and json.loads(mat["config"])["combine"]
    # MATLAB's column vectors (N x 1), not rows
    raw = loadmat(tmp_path / "out" / "results.mat")
    assert raw["detections"]["x"][0, 0].shape == (len(res["detections"]), 1)


def test_read_results_gives_dataframes_when_pandas_is_there(processed, monkeypatch):
    pd = pytest.importorskip("pandas")
    folder, _ = processed
    res = irdetect.read_results(folder / "res.h5")
    assert isinstance(res["tracks"], pd.DataFrame)
    arrays = irdetect.read_results(folder / "res.h5", as_frame=False)
    assert list(res["tracks"].columns) == list(arrays["tracks"].dtype.names)
    np.testing.assert_array_equal(res["detections"]["x"].to_numpy(), arrays["detections"]["x"])
    assert res.attrs == arrays.attrs and res.config == arrays.config
    real_import = builtins.__import__

    def no_pandas(name, *args, **kwargs):
        if name == "pandas":
            raise ImportError("No module named 'pandas'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_pandas)
    fallback = irdetect.read_results(folder / "res.h5")
    assert isinstance(fallback["tracks"], np.ndarray)
    with pytest.raises(ImportError, match=r"irdetect\[pandas\]"):
        irdetect.read_results(folder / "res.h5", as_frame=True)
