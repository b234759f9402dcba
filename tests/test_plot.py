"""`irdetect plot`: the accumulator picture finds the lines it was drawn from; the figure
is written, sized and coloured as promised; bad input fails cleanly."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from irdetect import tables
from irdetect.io import ResultsWriter, write_sequence
from irdetect.plot import accumulator
from irdetect.render import COLOURS
from irdetect.simulate import simulate

L = 12


def _line_detections(rng, lines, n_combined=8, clutter=6, size=(120, 160)):
    """Detections of straight constant-velocity targets (x0, y0, vx, vy per frame), one per
    combined frame at the window's middle frame, plus uniform clutter."""
    rows = []
    for k in range(n_combined):
        t = k * L + L / 2
        for x0, y0, vx, vy in lines:
            rows.append((x0 + vx * t + rng.normal(0, 0.3), y0 + vy * t + rng.normal(0, 0.3), k))
        for _ in range(clutter):
            rows.append((rng.uniform(0, size[1]), rng.uniform(0, size[0]), k))
    x, y, k = (np.array(c) for c in zip(*rows))
    k = k.astype(int)
    return tables.from_columns(tables.DETECTION, x=x, y=y, frame_start=k * L,
                               frame_end=k * L + L - 1, combined_frame=k)


def _line_params(x0, y0, vx, vy):
    theta = (math.atan2(vy, vx) + math.pi / 2) % math.pi
    return x0 * math.cos(theta) + y0 * math.sin(theta), theta


def test_accumulator_shows_peak_clustering_and_one_centre_per_line():
    rng = np.random.default_rng(2)
    lines = [(20.0, 30.0, 1.0, 0.5), (140.0, 20.0, -0.4, 0.9)]
    h = accumulator(_line_detections(rng, lines, clutter=2))
    assert h["n_scans"] == 8 and h["threshold"] == math.ceil(0.6 * 8)
    grid = h["grid"]
    # peak clustering: many cells pass the threshold, a few centres remain
    assert len(h["cells"]) > len(h["centres"]) >= 2
    for line in lines:
        rho, theta = _line_params(*line)
        d = [min(math.hypot((r - rho) / grid.drho, (t - theta) / grid.dtheta),
                 math.hypot((r + rho) / grid.drho, (abs(t - theta) - math.pi) / grid.dtheta))
             for r, t in h["centres"]]
        assert min(d) < 3.0, f"no centre within 3 cells of the line {line}"
    # every candidate cell does have >= T votes
    acc = h["acc"]
    assert (acc[tuple(h["cells"].T)] >= h["threshold"]).all()
    assert acc.shape == grid.shape


def test_accumulator_of_no_detections_is_empty():
    h = accumulator(tables.empty("detections"))
    assert len(h["cells"]) == 0 and len(h["centres"]) == 0 and h["acc"].sum() == 0


@pytest.fixture
def plotted(tmp_path):
    frames, truth = simulate("wan2008", rng=4, n_frames=48, height=60, width=80, n_targets=2,
                             snr=6.0, speed=[0.8, 1.0], directions=[10.0, 100.0])
    write_sequence(tmp_path / "seq.h5", frames, truth=truth)
    rows, tracks = [], []
    for tid in (0, 1):
        tr = truth[truth["target"] == tid]
        for k in range(4):
            p = tr[tr["frame"] == k * L + L // 2][0]
            rows.append((p["x"], p["y"], k))
        a, b = tr[0], tr[-1]
        n = b["frame"] - a["frame"]
        vx, vy = (b["x"] - a["x"]) / n, (b["y"] - a["y"]) / n
        rho, theta = _line_params(a["x"], a["y"], vx, vy)
        tracks.append(tables.from_columns(
            tables.TRACK, track_id=[tid], rho=[rho], theta=[theta], vx=[vx], vy=[vy],
            frame_start=[0], frame_end=[47], n_points=[4], score=[1.0], x0=[a["x"]],
            y0=[a["y"]]))
    x, y, k = (np.array(c) for c in zip(*rows))
    k = k.astype(int)
    det = tables.from_columns(tables.DETECTION, x=x, y=y, frame_start=k * L,
                              frame_end=k * L + L - 1, combined_frame=k)
    attrs = {"input": "seq.h5", "combined_length": L, "n_frames": 48, "frame_height": 60,
             "frame_width": 80, "config": "{}"}
    with ResultsWriter(tmp_path / "res.h5", attrs=attrs) as out:
        out.write("detections", det)
        out.write("tracks", np.concatenate(tracks))
    return tmp_path, np.concatenate(tracks)


def test_cli_plot_draws_tracks_and_accumulator(plotted, cli):
    folder, tracks = plotted
    code, _, err = cli("plot", folder / "res.h5", "-o", "fig.png", "--truth", "--scale", "4")
    assert code == 0, err
    img = cv2.imread(str(folder / "fig.png"))
    left = img[:240, :320]
    assert img.shape[0] == 240 and img.shape[1] > 320 + 6 + 200
    # each track's arrow runs over its estimated path in the left panel
    orange = np.abs(left.astype(int) - np.array(COLOURS["track"])).max(axis=2) < 50
    for row in tracks:
        t = np.linspace(0, 47, 9)[1:-1]
        xs = ((row["x0"] + row["vx"] * t) + 0.5) * 4 - 0.5
        ys = ((row["y0"] + row["vy"] * t) + 0.5) * 4 - 0.5
        hits = [orange[max(0, int(y) - 2):int(y) + 3, max(0, int(x) - 2):int(x) + 3].any()
                for x, y in zip(xs, ys)]
        assert all(hits), f"track {row['track_id']} not drawn along its path"
    # the right panel holds the cyan cluster centres and green track crosses
    right = img[:, 326:]
    cyan = np.abs(right.astype(int) - np.array([255, 255, 0])).max(axis=2) < 50
    green = np.abs(right.astype(int) - np.array(COLOURS["truth"])).max(axis=2) < 50
    assert cyan.sum() > 20 and green.sum() > 20


def test_cli_plot_without_the_sequence_and_bad_input(plotted, cli, tmp_path, caplog):
    folder, _ = plotted
    (folder / "seq.h5").rename(folder / "moved.h5")
    code, _, err = cli("plot", folder / "res.h5", "-o", "dark.png")
    assert code == 0 and "not found" in caplog.text         # warning, dark background
    assert cv2.imread(str(tmp_path / "dark.png")) is not None
    code, _, err = cli("plot", folder / "res.h5", "-o", "dark.png")
    assert code == 2 and "--force" in err
    code, _, err = cli("plot", folder / "res.h5", "-o", "fig.gif")
    assert code == 2 and "unknown image type" in err
    frames, _ = simulate("wan2008", rng=1, n_frames=48, height=50, width=80, n_targets=1,
                         directions=[0.0])
    write_sequence(folder / "other.h5", frames)
    code, _, err = cli("plot", folder / "res.h5", "-o", "x.png", "--sequence",
                       folder / "other.h5")
    assert code == 2 and "another sequence" in err and "Traceback" not in err
    assert not (tmp_path / "x.png").exists() and not (tmp_path / "fig.gif").exists()
