"""CLEAR-MOT and IDF1 on hand-computed cases and against py-motmetrics (test extra)."""

import warnings

import numpy as np
import pytest

from irdetect import tables
from irdetect.metrics.mot import clear_mot


def _truth(rows):
    f, t, x, y = zip(*rows)
    return tables.from_columns(tables.TRUTH, frame=f, target=t, x=x, y=y)


def _hyp(rows):
    f, t, x, y = zip(*rows)
    return tables.from_columns(tables.TRACK_POINT, frame=f, track_id=t, x=x, y=y)


def test_perfect_tracking():
    truth = _truth([(k, j, 10.0 * j + k, 5.0) for k in range(5) for j in range(2)])
    hyp = _hyp([(k, 7 + j, 10.0 * j + k + 0.5, 5.0) for k in range(5) for j in range(2)])
    r = clear_mot(truth, hyp, gate=3)
    assert (r["mota"], r["idf1"], r["id_switches"], r["fn"], r["fp"]) == (1.0, 1.0, 0, 0, 0)
    assert r["motp"] == pytest.approx(0.5)


def test_one_id_switch():
    # one object over 4 frames; track 1 follows it in frames 0-1, track 2 in frames 2-3
    truth = _truth([(k, 0, float(k), 0.0) for k in range(4)])
    hyp = _hyp([(0, 1, 0.0, 0.0), (1, 1, 1.0, 0.0), (2, 2, 2.0, 1.0), (3, 2, 3.0, 1.0)])
    r = clear_mot(truth, hyp, gate=2)
    assert r["id_switches"] == 1
    assert r["mota"] == pytest.approx(1 - 1 / 4)
    assert r["motp"] == pytest.approx(0.5)
    assert r["idf1"] == pytest.approx(2 * 2 / (4 + 4))            # best pair shares 2 frames


def test_misses_false_positives_and_gate():
    # frame 0: both matched; frame 1: object 1 missed, a false track far away; frame 2: extra
    truth = _truth([(0, 0, 0, 0), (0, 1, 10, 0), (1, 0, 1, 0), (1, 1, 11, 0), (2, 0, 2, 0)])
    hyp = _hyp([(0, 5, 0, 0), (0, 6, 10, 1), (1, 5, 1, 0), (1, 9, 50, 50), (2, 5, 2, 0),
                (2, 6, 30, 0)])
    r = clear_mot(truth, hyp, gate=2)
    assert (r["matches"], r["fn"], r["fp"], r["id_switches"]) == (4, 1, 2, 0)
    assert r["mota"] == pytest.approx(1 - 3 / 5)
    assert r["motp"] == pytest.approx(1 / 4)
    assert r["idf1"] == pytest.approx(2 * 4 / (5 + 6))
    # a gate of 0.5 px rejects the 1 px match of object 1 in frame 0
    assert clear_mot(truth, hyp, gate=0.5)["matches"] == 3


def test_keeps_last_correspondence_over_a_closer_newcomer():
    # track 1 follows the object; in frame 1 track 2 lands closer, but 1 is still in the gate
    truth = _truth([(0, 0, 0, 0), (1, 0, 0, 0)])
    hyp = _hyp([(0, 1, 0.5, 0), (1, 1, 1.5, 0), (1, 2, 0.1, 0)])
    r = clear_mot(truth, hyp, gate=2)
    assert (r["id_switches"], r["fp"]) == (0, 1)


def test_empty_inputs_and_bad_gate():
    e_t, e_h = tables.empty(tables.TRUTH), tables.empty(tables.TRACK_POINT)
    truth = _truth([(0, 0, 0, 0)])
    r = clear_mot(truth, e_h, gate=1)
    assert (r["mota"], r["fn"], r["idf1"]) == (0.0, 1, 0.0)
    assert np.isnan(clear_mot(e_t, e_h, gate=1)["mota"])
    with pytest.raises(ValueError, match="gate must be > 0"):
        clear_mot(truth, e_h, gate=0)
    with pytest.raises(ValueError, match="lacks fields"):
        clear_mot(truth, np.zeros(1, [("frame", int)]), gate=1)


def test_matches_py_motmetrics():
    import motmetrics as mm  # the reference, installed by the test extra
    rng = np.random.default_rng(5)
    truth_rows, hyp_rows = [], []
    for k in range(40):
        for j in range(3):
            x, y = 20.0 * j + 0.5 * k, 10.0 + 3 * j
            truth_rows.append((k, j, x, y))
            if rng.random() < 0.85:                   # misses
                tid = j + 10 * (k // 15) if j == 1 else j   # target 1 changes id twice
                hyp_rows.append((k, tid, x + rng.normal(0, 0.7), y + rng.normal(0, 0.7)))
        if rng.random() < 0.3:                        # clutter
            hyp_rows.append((k, 100 + k, rng.uniform(0, 60), rng.uniform(0, 30)))
    truth, hyp = _truth(truth_rows), _hyp(hyp_rows)
    gate = 2.0
    mine = clear_mot(truth, hyp, gate=gate)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        acc = mm.MOTAccumulator(auto_id=False)
        for k in range(40):
            t, h = truth[truth["frame"] == k], hyp[hyp["frame"] == k]
            d = mm.distances.norm2squared_matrix(np.column_stack([t["x"], t["y"]]),
                                                 np.column_stack([h["x"], h["y"]]),
                                                 max_d2=gate ** 2)
            acc.update(t["target"].tolist(), h["track_id"].tolist(), np.sqrt(d), frameid=k)
        s = mm.metrics.create().compute(acc, metrics=["mota", "motp", "idf1", "num_switches",
                                                      "num_misses", "num_false_positives"])
    assert mine["id_switches"] == int(s["num_switches"].iloc[0]) >= 2
    assert mine["fn"] == int(s["num_misses"].iloc[0])
    assert mine["fp"] == int(s["num_false_positives"].iloc[0])
    assert mine["mota"] == pytest.approx(float(s["mota"].iloc[0]), abs=1e-9)
    assert mine["motp"] == pytest.approx(float(s["motp"].iloc[0]), abs=1e-9)
    assert mine["idf1"] == pytest.approx(float(s["idf1"].iloc[0]), abs=1e-9)
