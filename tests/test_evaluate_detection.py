"""Detection scores: Pd one-to-one within the gate, false detections, pixel-level Fa; the CLI."""

import json

import numpy as np
import pytest

from irdetect import tables
from irdetect.io import write_sequence
from irdetect.metrics.detection import path_distance, roc, score_detections
from irdetect.pipeline import detect_sequence
from irdetect.simulate import simulate


def _truth():
    # target 0 moves 1 px/frame along y = 10 from x = 10 over 24 frames (2 windows of 12)
    f = np.arange(24)
    return tables.from_columns(tables.TRUTH, frame=f, target=np.zeros(24, int),
                               x=10.0 + f, y=np.full(24, 10.0), amplitude=np.ones(24))


def _dets(rows):
    out = np.zeros(len(rows), tables.DETECTION)
    for i, (x, y, k) in enumerate(rows):
        out[i]["x"], out[i]["y"], out[i]["combined_frame"] = x, y, k
    return out


def test_path_distance():
    path = np.array([[0.0, 0.0], [10.0, 0.0]])
    d = path_distance(np.array([[5.0, 3.0], [-4.0, 3.0], [12.0, 0.0]]), path)
    np.testing.assert_allclose(d, [3.0, 5.0, 2.0])
    assert path_distance(np.array([[3.0, 4.0]]), np.zeros((1, 2)))[0] == pytest.approx(5.0)


def test_one_to_one_matching_false_detections_and_pixel_fa():
    dets = _dets([(15.0, 11.0, 0),      # on window 0's path (x 10..21): detected
                  (16.0, 10.0, 0),      # a second detection of the same target: false
                  (40.0, 40.0, 0),      # far away: false
                  (30.0, 12.9, 1),      # window 1 path x 22..33, 2.9 px off: detected
                  (45.0, 10.0, 1)])     # beyond the path's end (12 px): false
    m = score_detections(dets, _truth(), n_frames=24, length=12, step=12, shape=(100, 200))
    assert m["windows"] == 2 and m["targets"] == 2 and m["detected"] == 2 and m["pd"] == 1.0
    assert m["false"] == 3 and m["false_per_window"] == 1.5
    assert m["false_per_mpx_window"] == pytest.approx(1.5 / 0.02)
    assert m["pixel_fa"] == pytest.approx(27 / (2 * 100 * 200))   # three 3x3 squares
    tight = score_detections(dets, _truth(), n_frames=24, length=12, step=12,
                             shape=(100, 200), gate=2.0)
    assert tight["detected"] == 1 and tight["false"] == 4


def test_presence_rule_sets_aside_a_target_seen_in_part_of_its_window():
    # target 0 inside in all 24 frames; target 1 enters at frame 16: 8 of window 1's 12
    # frames (0.67), target 2 leaves after frame 2: 3 of window 0's 12
    t0, t1, t2 = _truth(), _truth(), _truth()
    t1["target"], t1["y"] = 1, 50.0
    t2["target"], t2["y"] = 2, 80.0
    truth = np.concatenate([t0, t1[t1["frame"] >= 16], t2[t2["frame"] < 3]])
    dets = _dets([(15.0, 10.0, 0), (11.0, 80.0, 0),     # target 0; target 2 (3 frames)
                  (30.0, 10.0, 1), (30.0, 50.0, 1),     # target 0; target 1 (8 frames)
                  (60.0, 60.0, 1)])                     # nothing near: false
    kw = dict(n_frames=24, length=12, step=12, shape=(100, 200))
    every = score_detections(dets, truth, **kw)
    assert (every["targets"], every["detected"], every["false"]) == (4, 4, 1)
    ruled = score_detections(dets, truth, presence=0.75, **kw)
    assert (ruled["targets"], ruled["detected"], ruled["false"]) == (2, 2, 1)
    assert ruled["set_aside"] == 2 and every["set_aside"] == 0
    # the ROC follows the rule: target 1 (8 frames) missed is no missed target-window
    missed = dets[[0, 1, 2, 4]]
    assert score_detections(missed, truth, **kw)["pd"] == 0.75
    curve = roc(missed, truth, presence=0.75, **kw)
    assert curve["pd"][-1] == 1.0 and curve["false_per_frame"][-1] == 1 / 24
    # at 0.6 target 1 (0.67 of its window) counts again
    assert score_detections(dets, truth, presence=0.6, **kw)["targets"] == 3
    with pytest.raises(ValueError, match="presence"):
        score_detections(dets, truth, presence=1.5, **kw)
    # rows of the truth outside the frame are not presence: target 2 given in all 12
    # frames of window 0, but out of view (x < 0) in 6 of them, is still set aside
    t2 = _truth()[:12]
    t2["target"], t2["y"], t2["x"] = 2, 80.0, 2.0 * t2["frame"] - 11.0
    out = np.concatenate([t0, t1[t1["frame"] >= 16], t2])
    assert score_detections(dets, out, presence=0.75, **kw)["set_aside"] == 2


def test_no_detections_and_no_truth():
    m = score_detections(_dets([]), _truth(), n_frames=24, length=12, step=12, shape=(50, 50))
    assert m["pd"] == 0.0 and m["false"] == 0 and m["pixel_fa"] == 0.0
    empty = tables.empty(tables.TRUTH)
    m = score_detections(_dets([(1, 1, 0)]), empty, n_frames=24, length=12, step=12,
                         shape=(50, 50))
    assert np.isnan(m["pd"]) and m["false"] == 1
    with pytest.raises(ValueError, match="gate"):
        score_detections(_dets([]), empty, n_frames=24, length=12, step=12, shape=(5, 5),
                         gate=0)


def test_cli_process_then_evaluate(cli, tmp_path):
    frames, truth = simulate("wan2008", snr=6, rng=2, n_frames=48, height=96, width=128,
                             n_targets=2, directions=(0.0, 90.0))
    write_sequence(tmp_path / "seq.h5", frames, truth=truth)
    code, _, err = cli("process", "seq.h5", "-o", "res.h5", "-q")
    assert code == 0, err
    code, out, _ = cli("evaluate", "res.h5", "--truth", "seq.h5", "--json")
    assert code == 0
    scores = json.loads(out)["detection"]
    # the two targets cross in the last window (one fused point of the combined-frame
    # path there; the per-frame path follows both); nothing false
    assert scores["targets"] == 8 and scores["detected"] >= 7 and scores["false"] == 0
    mem = score_detections(detect_sequence(frames)["detections"], truth, n_frames=48,
                           length=12, step=12, shape=(96, 128))
    assert mem == pytest.approx({k: scores[k] for k in mem})
    # the ROC over the local SNR: its last point holds every detection
    assert scores["roc"]["pd"][-1] == scores["pd"] and 0 < scores["roc_auc"] <= 1
    code, out, _ = cli("evaluate", "res.h5")            # truth from the results' input
    assert code == 0 and "pd" in out and "false_per_mpx_window" in out
    # the presence rule: both targets stay inside, so the same counts, none set aside
    code, out, _ = cli("evaluate", "res.h5", "--presence", "0.75", "--json")
    ruled = json.loads(out)["detection"]
    assert code == 0 and ruled["set_aside"] == 0 and ruled["roc"]["pd"][-1] == ruled["pd"]
    assert {k: ruled[k] for k in ("targets", "detected", "false")} == {
        k: scores[k] for k in ("targets", "detected", "false")}
    # point annotations (x y per frame) are accepted as truth too
    lines = "\n".join(f"{x} {y}" for x, y in truth[truth["target"] == 0][["x", "y"]].tolist())
    (tmp_path / "truth.txt").write_text(lines + "\n")
    code, out, _ = cli("evaluate", "res.h5", "--truth", "truth.txt", "--json")
    assert code == 0 and json.loads(out)["detection"]["targets"] == 4


def test_cli_evaluate_bad_input(cli, tmp_path):
    frames, _ = simulate("wan2008", snr=4, rng=2, n_frames=48, height=64, width=64,
                         n_targets=1, directions=(0.0,))
    write_sequence(tmp_path / "notruth.h5", frames)
    code, _, err = cli("process", "notruth.h5", "-o", "res.h5", "-q")
    assert code == 0
    code, _, err = cli("evaluate", "res.h5", "--truth", "notruth.h5")
    assert code == 2 and "no ground truth" in err and "Traceback" not in err
    code, _, err = cli("evaluate", "missing.h5", "--truth", "notruth.h5")
    assert code == 2 and "not found" in err
    code, _, err = cli("evaluate", "res.h5", "--truth", "notruth.h5", "--gate", "-1")
    assert code == 2 and "--gate" in err
    code, _, err = cli("evaluate", "res.h5", "--truth", "notruth.h5", "--presence", "1.5")
    assert code == 2 and "--presence" in err and "Traceback" not in err


def test_the_table_gives_the_roc_at_a_few_false_alarm_rates():
    from irdetect.commands.evaluate import ROC_RATES, format_table

    curve = {"thresholds": [np.inf, 9.0, 6.0, 4.0, 3.0], "pd": [0.0, 0.5, 0.75, 0.9, 1.0],
             "false_per_frame": [0.0, 0.0, 0.005, 0.05, 0.4]}
    text = format_table({"detection": {"pd": 1.0, "roc": curve}})
    rows = [line.split() for line in text.splitlines()[3:3 + len(ROC_RATES) + 1]]
    # best Pd with at most 0, 0.001, 0.01, 0.1 false per frame, then every detection
    assert rows == [["0", "0.5", "9"], ["0.001", "0.5", "9"], ["0.01", "0.75", "6"],
                    ["0.1", "0.9", "4"], ["all", "1", "3"]]
    assert "--json" in text.splitlines()[3 + len(ROC_RATES) + 1]
