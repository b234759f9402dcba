"""Track-initiation scores through the CLI: `process` results and `initiate` results."""

import json

import numpy as np
import pytest

from irdetect.cli import main
from irdetect.io import write_sequence
from irdetect.simulate import simulate


def _json(capsys, argv):
    capsys.readouterr()
    assert main(argv) == 0
    return json.loads(capsys.readouterr().out)


def test_evaluate_scores_the_tracks_of_process(tmp_path, capsys):
    frames, truth = simulate("wan2008", snr=4, rng=3, n_frames=48, height=120, width=160,
                             n_targets=3, directions=[0.0, 120.0, 240.0])
    seq, out = tmp_path / "seq.h5", tmp_path / "seq.irdetect.h5"
    write_sequence(seq, frames, truth=truth)
    assert main(["process", str(seq), "-o", str(out), "-q"]) == 0
    scores = _json(capsys, ["evaluate", str(out), "--json"])["track initiation"]
    assert scores["pt_overall"] == 1.0 and scores["n_false"] == 0
    assert [scores[f"pt target {j}"] for j in range(3)] == [1.0, 1.0, 1.0]
    assert scores["speed_error_median"] < 0.1
    assert scores["n_false_path"] == 0 and scores["false_path_tracks"] == []


def test_evaluate_scores_the_scan_tracks_of_initiate(tmp_path, capsys):
    scans, out = tmp_path / "s.h5", tmp_path / "o.h5"
    assert main(["simulate-scans", str(scans), "--scenario", "zhang2010", "--seed", "4",
                 "--clutter-density", "0.03", "-q"]) == 0
    assert main(["initiate", str(scans), "-o", str(out), "--window", "5", "-q"]) == 0
    scores = _json(capsys, ["evaluate", str(out), "--json"])["track initiation (scans)"]
    # two windows of 5 scans, 3 targets each: every target in both
    assert scores["pt_overall"] == 1.0 and scores["n_tracks"] >= 6
    assert scores["pc"] == scores["n_false"] / scores["n_tracks"]
    assert np.isfinite(scores["ospa_mean"]) and scores["ospa_mean"] < 1000.0
    # the same with the truth named explicitly
    again = _json(capsys, ["evaluate", str(out), "--truth", str(scans), "--json"])
    assert again["track initiation (scans)"] == scores


def test_path_rule_holds_a_wiggling_target_and_rejects_a_track_out_of_time():
    from irdetect import tables
    from irdetect.metrics.initiation import score_image_tracks, score_track_paths

    f = np.arange(100)
    truth = tables.from_columns(tables.TRUTH, frame=f, target=np.zeros(100, int),
                                x=50 + 0.5 * f, y=80 + 0.2 * f + 6 * np.sin(f / 5))
    on = dict(frame_start=0, frame_end=99, vx=0.5, vy=0.2, x0=50.0, y0=80.0)
    late = dict(on, x0=30.0, y0=72.0)                        # its line, 40 frames behind
    tracks = tables.from_columns(tables.TRACK, n=3)
    for i, tr in enumerate((on, late, on)):                 # the third duplicates the first
        for name, value in tr.items():
            tracks[name][i] = value
    theta = np.arctan2(0.2, 0.5) + np.pi / 2
    tracks["theta"], tracks["rho"] = theta, 50 * np.cos(theta) + 80 * np.sin(theta)
    tracks["track_id"] = [10, 11, 12]
    path = score_track_paths(tracks, truth, gate=6.0)
    assert path["pt_overall"] == 1.0 and path["n_false"] == 2      # the late one, the copy
    assert len(path["false_ids"]) == 2 and 11 in path["false_ids"]     # named by track_id
    assert score_track_paths(tracks[1:2], truth, gate=6.0)["pt_overall"] == 0.0
    # the target's track broken in two (frames 0-49 and 50-99) is no false track; a
    # second one beside it over the same frames is
    halves = tracks[[0, 0]].copy()
    halves["frame_end"][0], halves["frame_start"][1] = 49, 50
    halves["x0"][1], halves["y0"][1] = 75.0, 90.0
    assert score_track_paths(halves, truth, gate=6.0)["n_false"] == 0
    line = score_image_tracks(tracks, truth, sigma=1.5)       # the line rule: a 5.6 px
    assert line["pt_overall"] == 0.0                          # wiggle is beyond 3 x 1.5 px


def test_line_rule_measures_a_scene_track_in_scene_coordinates():
    # a target straight in the scene under a camera panning (3, -2) px/frame: in the
    # image it moves (3.5, -1.8) px/frame; the scene track's line and velocity are the
    # scene's (irdetect process under a moving camera), its rho given relative to the
    # camera's offset at its first frame
    from irdetect import tables
    from irdetect.metrics.initiation import score_image_tracks

    f = np.arange(60)
    camera = np.column_stack([3.0 * f, -2.0 * f])
    truth = tables.from_columns(tables.TRUTH, frame=f, target=np.zeros(60, int),
                                x=40 + 0.5 * f + camera[:, 0], y=300 + 0.2 * f + camera[:, 1])
    tracks = tables.from_columns(tables.TRACK, n=1)
    start = 10
    x0, y0 = truth["x"][start], truth["y"][start]
    theta = np.arctan2(0.2, 0.5) + np.pi / 2
    for name, value in dict(frame_start=start, frame_end=59, vx=0.5, vy=0.2, x0=x0, y0=y0,
                            theta=theta, rho=x0 * np.cos(theta) + y0 * np.sin(theta),
                            scene=True).items():
        tracks[name][0] = value
    line = score_image_tracks(tracks, truth, sigma=1.5, camera=camera)
    assert line["pt_overall"] == 1.0 and line["n_false"] == 0
    assert line["speed_error"][0] < 1e-9                 # against the scene's velocity
    # the same track taken for an image line (the rule before): false
    image = tracks.copy()
    image["scene"] = False
    assert score_image_tracks(image, truth, sigma=1.5)["n_false"] == 1
    with pytest.raises(ValueError, match="camera"):
        score_image_tracks(tracks, truth, sigma=1.5)
