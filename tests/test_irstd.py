"""IRSTD Pd / Fa (irdetect.metrics.irstd) on hand-computed cases and against pyirstdmetrics
1.0.2, the field's reference (installed for the tests without its dependencies by
scripts/_venv.sh: it pins numpy<2)."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from irdetect import tables
from irdetect.metrics.irstd import (draw_discs, pd_fa, score_irstd_detections,
                                    score_irstd_points, truth_at)


def _reference():
    return pytest.importorskip("py_irstd_metrics")


def _reference_pd_fa(predicted, truth, distance):
    """pyirstdmetrics' target-wise Pd / Fa fed the masks image by image."""
    ref = _reference().ProbabilityDetectionAndFalseAlarmRate(num_bins=1,
                                                              distance_threshold=distance)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for p, t in zip(predicted, truth):
            ref.update(p.astype(float), t.astype(bool))
        got = ref.get()
    return (float(got["probability_detection"][0]), float(got["false_alarm"][0]),
            int(ref.tp_objs[0]), int(ref.fp_area[0]), int(ref.total_area))


def test_discs_and_a_hand_computed_image():
    one = draw_discs(np.array([[5.0, 5.0]]), (10, 10))
    assert one.sum() == 9 and one[4:7, 4:7].all()                 # 3 x 3 px
    assert draw_discs(np.array([[0.0, 0.0]]), (10, 10)).sum() == 4   # clipped at the corner
    assert draw_discs(np.array([[5.4, 5.0]]), (10, 10), 0.2).sum() == 1  # its own pixel
    assert draw_discs(np.zeros((0, 2)), (4, 4)).sum() == 0
    with pytest.raises(ValueError, match="radius"):
        draw_discs(np.array([[1.0, 1.0]]), (4, 4), -1)
    truth = draw_discs(np.array([[10.0, 10.0], [30.0, 10.0]]), (40, 40))
    pred = draw_discs(np.array([[12.0, 10.0],                 # 2 px: detects the first
                                [33.0, 10.0],                 # 3 px: not < 3, a false region
                                [20.0, 30.0]]), (40, 40))     # far: false
    s = pd_fa(pred, truth)
    assert (s["targets"], s["detected"], s["regions"], s["false_pixels"]) == (2, 1, 3, 18)
    assert s["irstd_pd"] == 0.5 and s["irstd_fa"] == 18 / 1600
    assert pd_fa(pred, truth, distance=3.5)["detected"] == 2
    assert np.isnan(pd_fa(np.zeros((2, 5, 5), bool), np.zeros((2, 5, 5), bool))["irstd_pd"])
    with pytest.raises(ValueError, match="one shape"):
        pd_fa(pred, truth[:-1])
    with pytest.raises(ValueError, match="distance"):
        pd_fa(pred, truth, distance=0)


def test_a_region_is_taken_once_in_raster_order():
    # two targets 2 px either side of one predicted region: the first in raster order
    # (the upper one) takes it, the other is missed; the region counts no false pixel
    truth = np.zeros((20, 20), bool)
    truth[5, 10] = truth[9, 10] = True
    pred = draw_discs(np.array([[10.0, 7.0]]), (20, 20), 1.0)
    s = pd_fa(pred, truth)
    assert (s["targets"], s["detected"], s["false_pixels"]) == (2, 1, 0)


def _random_masks(rng, n_images, shape=(48, 64)):
    pred, truth = [], []
    for _ in range(n_images):
        n_t = rng.integers(0, 5)
        t_xy = rng.uniform(-2, [shape[1] + 2, shape[0] + 2], (n_t, 2))
        near = t_xy[rng.random(n_t) < 0.7]
        near = near + rng.normal(0, 1.8, near.shape)             # detections near targets
        clutter = rng.uniform(0, [shape[1], shape[0]], (rng.integers(0, 6), 2))
        p_xy = np.concatenate([near, clutter])
        truth.append(draw_discs(t_xy, shape, rng.uniform(0.5, 3.0, n_t)))
        pred.append(draw_discs(p_xy, shape, rng.uniform(0.3, 4.0, len(p_xy))))
    return np.array(pred), np.array(truth)


@pytest.mark.parametrize("distance", [1, 3, 5])
def test_matches_pyirstdmetrics_on_random_masks(distance):
    rng = np.random.default_rng(29 + distance)
    pred, truth = _random_masks(rng, 120)
    mine = pd_fa(pred, truth, distance=distance)
    pd, fa, tp, fp_area, total = _reference_pd_fa(pred, truth, distance)
    assert (mine["detected"], mine["false_pixels"], mine["pixels"]) == (tp, fp_area, total)
    assert mine["irstd_pd"] == pytest.approx(pd, abs=1e-12)
    assert mine["irstd_fa"] == pytest.approx(fa, abs=1e-15)
    assert 0 < mine["detected"] < mine["targets"] and mine["false_pixels"] > 0


def test_truth_at_interpolates_between_frames():
    truth = tables.from_columns(tables.TRUTH, frame=[0, 1, 2, 1], target=[0, 0, 0, 1],
                                x=[0.0, 2.0, 4.0, 9.0], y=[1.0, 1.0, 1.0, 7.0])
    image, xy = truth_at(truth, np.array([0.5, 1.0, 1.5, 2.0, 7.0]))
    got = sorted(zip(image.tolist(), xy[:, 0].tolist(), xy[:, 1].tolist()))
    # target 1 lives in frame 1 only: at times 0.5 and 1.5 its one frame's position
    assert got == [(0, 1.0, 1.0), (0, 9.0, 7.0), (1, 2.0, 1.0), (1, 9.0, 7.0),
                   (2, 3.0, 1.0), (2, 9.0, 7.0), (3, 4.0, 1.0)]


def _evaluate_json(cli, results):
    code, out, err = cli("evaluate", results, "--irstd", "--json")
    assert code == 0, err
    return json.loads(out)["IRSTD (pyirstdmetrics)"]


def test_evaluate_irstd_of_process_matches_pyirstdmetrics(tmp_path, cli):
    """`evaluate --irstd` on a process run equals pyirstdmetrics fed the same masks: one
    image per window, detections as 3x3 discs, the truth at the windows' middle times."""
    from irdetect.io import read_results
    from irdetect.io.sources import open_sequence

    assert cli("simulate", "seq.h5", "--snr", "3", "--seed", "4", "--frames", "48",
               "--size", "96x80", "--targets", "4", "-q")[0] == 0
    assert cli("process", "seq.h5", "-o", "res.h5", "-q")[0] == 0
    mine = _evaluate_json(cli, "res.h5")
    res = read_results(tmp_path / "res.h5")
    with open_sequence(tmp_path / "seq.h5") as src:
        truth = src.truth
    det = res["detections"]
    length, n_win = int(res.attrs["combined_length"]), int(res.attrs["n_combined"])
    times = np.arange(n_win) * length + (length - 1) / 2
    t_image, t_xy = truth_at(truth, times)
    pred = np.array([draw_discs(np.column_stack([det["x"], det["y"]])[det["combined_frame"]
                                                                       == k], (80, 96))
                     for k in range(n_win)])
    tru = np.array([draw_discs(t_xy[t_image == k], (80, 96)) for k in range(n_win)])
    assert mine == pytest.approx(pd_fa(pred, tru, distance=3.0))
    pd, fa, tp, fp_area, total = _reference_pd_fa(pred, tru, 3)
    assert (mine["detected"], mine["false_pixels"], mine["pixels"]) == (tp, fp_area, total)
    assert mine["irstd_pd"] == pytest.approx(pd) and mine["irstd_fa"] == pytest.approx(fa)
    assert mine["images"] == n_win and mine["targets"] >= 12 and mine["detected"] >= 8


def test_evaluate_irstd_of_track_draws_regions_by_area(tmp_path, cli):
    from irdetect.io import read_results
    from irdetect.io.sources import open_sequence

    assert cli("simulate", "h.h5", "--scenario", "harbour", "--seed", "1", "--frames", "30",
               "-q")[0] == 0
    assert cli("track", "h.h5", "-o", "t.h5", "--profile", "maritime", "-q")[0] == 0
    mine = _evaluate_json(cli, "t.h5")
    pts = read_results(tmp_path / "t.h5")["track_points"]
    with open_sequence(tmp_path / "h.h5") as src:
        truth, (n, h, w) = src.truth, src.shape
    area = np.where(pts["area"] > 0, pts["area"], np.pi * 1.5 ** 2)
    pred = np.array([draw_discs(np.column_stack([pts["x"], pts["y"]])[pts["frame"] == k],
                                (h, w), np.sqrt(area[pts["frame"] == k] / np.pi))
                     for k in range(n)])
    tru = np.array([draw_discs(np.column_stack([truth["x"], truth["y"]])[truth["frame"] == k],
                               (h, w)) for k in range(n)])
    pd, fa, tp, fp_area, total = _reference_pd_fa(pred, tru, 3)
    assert (mine["detected"], mine["false_pixels"], mine["pixels"]) == (tp, fp_area, total)
    assert mine["irstd_pd"] == pytest.approx(pd) and mine["irstd_fa"] == pytest.approx(fa)
    assert mine["images"] == n and mine["regions"] > 0


def test_score_functions_keep_to_their_images():
    truth = tables.from_columns(tables.TRUTH, frame=[0, 1], target=[0, 0], x=[5.0, 6.0],
                                y=[5.0, 5.0])
    det = tables.from_columns(tables.DETECTION, x=[5.0, 50.0], y=[5.0, 5.0],
                              combined_frame=[0, 7])          # window 7 does not exist
    s = score_irstd_detections(det, truth, n_frames=2, length=2, step=2, shape=(10, 10))
    assert (s["images"], s["targets"], s["detected"], s["regions"]) == (1, 1, 1, 1)
    pts = tables.from_columns(tables.TRACK_POINT, frame=[0, 1, 5], x=[5.0, 6.0, 1.0],
                              y=[5.0, 5.0, 1.0], area=[np.nan, 20.0, 4.0])
    s = score_irstd_points(pts, truth, n_frames=2, shape=(10, 10))
    assert (s["images"], s["targets"], s["detected"], s["pixels"]) == (2, 2, 2, 200)


def test_irstd_on_scans_results_is_one_line(tmp_path, cli):
    assert cli("simulate-scans", "s.h5", "--scans", "6", "--seed", "1", "-q")[0] == 0
    assert cli("initiate", "s.h5", "-o", "i.h5", "-q")[0] == 0
    code, _, err = cli("evaluate", "i.h5", "--irstd")
    assert code == 2 and err.strip().splitlines() == [
        "irdetect evaluate: error: i.h5: --irstd scores image detections; this holds "
        "tracks on scans"]
