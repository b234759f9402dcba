"""`irdetect plot`: the accumulator picture finds the lines it was drawn from; the figure
is written, sized and coloured as promised; bad input fails cleanly."""

from __future__ import annotations

import builtins
import math
import os

import cv2
import numpy as np
import pytest

from irdetect import tables
from irdetect.io import ResultsWriter, write_sequence
from irdetect.plot import accumulator
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


def _near(mask, x, y, r=3):
    """Any True in ``mask`` within r px of image pixel (x, y)."""
    x, y = int(round(x)), int(round(y))
    return mask[max(0, y - r):y + r + 1, max(0, x - r):x + r + 1].any()


def _colour_mask(rgb_image, colour, tol=60):
    return np.abs(rgb_image.astype(int) - 255 * np.array(colour)).max(axis=2) < tol


def test_cli_plot_draws_tracks_and_accumulator(plotted, cli):
    from irdetect.plot import PLOT_COLOURS

    folder, tracks = plotted
    old = os.umask(0o022)
    try:
        code, _, err = cli("plot", folder / "res.h5", "-o", "fig.png", "--truth", "--scale", "4")
    finally:
        os.umask(old)
    assert code == 0, err
    assert (folder / "fig.png").stat().st_mode & 0o777 == 0o644
    img = cv2.cvtColor(cv2.imread(str(folder / "fig.png")), cv2.COLOR_BGR2RGB)
    assert img.shape[1] > 2 * 320
    # the legend's colours are in the picture: tracks, truth, detections, cluster centres
    for name in ("track", "truth", "centre"):
        assert _colour_mask(img, PLOT_COLOURS[name]).sum() > 30, name
    assert _colour_mask(img, PLOT_COLOURS["windows"][1]).sum() > 10      # window 1: magenta


def test_plot_truth_shows_where_truth_lies(plotted):
    """The figure's left axes map (x, y) px to figure pixels: the truth is green there,
    drawn over the track line that runs along it."""
    from irdetect.io import open_sequence, read_results
    from irdetect.plot import PLOT_COLOURS, plot_results, write_figure

    folder, tracks = plotted
    results = read_results(folder / "res.h5")
    with open_sequence(folder / "seq.h5") as src:
        truth = src.truth
        fig = plot_results(results, src, truth=truth, scale=4)
    write_figure(folder / "t.png", fig)
    fig.canvas.draw()
    img = cv2.cvtColor(cv2.imread(str(folder / "t.png")), cv2.COLOR_BGR2RGB)
    assert img.shape[:2] == fig.canvas.get_width_height()[::-1]
    green = _colour_mask(img, PLOT_COLOURS["truth"])
    ax = fig.axes[0]
    shown = truth[::2]                              # the figure marks every 2nd frame
    px = ax.transData.transform(np.column_stack([shown["x"], shown["y"]]))
    rows = img.shape[0] - px[:, 1]                  # matplotlib counts rows from the bottom
    hits = [_near(green, x, y) for x, y in zip(px[:, 0], rows)]
    assert np.mean(hits) > 0.9
    # and not everywhere: a band away from every target holds no green
    far = ax.transData.transform([[2.0, 57.0]])[0]
    assert not _near(green, far[0], img.shape[0] - far[1], r=4)
    # the Hough axes are labelled in real units
    hough = fig.axes[1]
    assert "theta" in hough.get_xlabel() and "deg" in hough.get_xlabel()
    assert "rho" in hough.get_ylabel() and "px" in hough.get_ylabel()
    assert hough.get_xlim() == (0.0, 180.0)
    assert any("votes" in a.get_ylabel() for a in fig.axes[2:])          # the colour bar


def test_plot_without_matplotlib_says_what_to_install(plotted, cli, monkeypatch):
    folder, _ = plotted
    real_import = builtins.__import__

    def no_matplotlib(name, *args, **kwargs):
        if name.startswith("matplotlib"):
            raise ImportError("No module named 'matplotlib'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_matplotlib)
    code, _, err = cli("plot", folder / "res.h5", "-o", "none.png")
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "pip install irdetect[plot]" in err
    assert not (folder / "none.png").exists()


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


def test_plot_finds_the_input_where_process_read_it(tmp_path, cli, monkeypatch, caplog):
    # results written to another folder, plot run from a third: the input is found by the
    # path process recorded (input_path), as evaluate finds it, not only beside the results
    frames, truth = simulate("wan2008", rng=2, n_frames=36, height=48, width=64, n_targets=1,
                             snr=8.0)
    (tmp_path / "data").mkdir()
    (tmp_path / "out").mkdir()
    (tmp_path / "elsewhere").mkdir()
    write_sequence(tmp_path / "data" / "seq.h5", frames, truth=truth)
    code, _, err = cli("process", tmp_path / "data" / "seq.h5", "-o",
                       tmp_path / "out" / "res.h5", "-q")
    assert code == 0, err
    monkeypatch.chdir(tmp_path / "elsewhere")
    code, _, err = cli("plot", tmp_path / "out" / "res.h5", "-o", "fig.png", "--truth")
    assert code == 0, err
    assert "not found" not in caplog.text
    assert cv2.imread("fig.png") is not None
    from irdetect.commands import find_sequence
    from irdetect.io import read_results
    assert find_sequence(read_results(tmp_path / "out" / "res.h5")) == tmp_path / "data" / "seq.h5"


def test_plot_draws_the_tracker_paths_of_track_results(tmp_path, cli):
    """The results of irdetect track: one panel, each path in the tracker's colour where
    its points are, no Hough panel (there are no detections to vote)."""
    from irdetect.plot import PLOT_COLOURS, plot_results
    from irdetect.io import open_sequence, read_results

    frames, truth = simulate("wan2008", rng=4, n_frames=40, height=60, width=80,
                             n_targets=2, snr=10.0, speed=[1.0, 1.0], directions=[10.0, 100.0])
    write_sequence(tmp_path / "seq.h5", frames, truth=truth)
    code, _, err = cli("track", "seq.h5", "-o", "t.h5", "-q")
    assert code == 0, err
    res = read_results(tmp_path / "t.h5")
    pts = res["track_points"]
    assert len(np.unique(pts["track_id"])) == 2
    with open_sequence(tmp_path / "seq.h5") as src:
        fig = plot_results(res, src, scale=4)
    assert len(fig.axes) == 1
    fig.canvas.draw()
    img = np.asarray(fig.canvas.buffer_rgba())[..., :3]
    yellow = _colour_mask(img, PLOT_COLOURS["tracker"])
    to_fig = fig.axes[0].transData
    h = img.shape[0]
    for p in pts[::7]:
        fx, fy = to_fig.transform((p["x"], p["y"]))
        assert _near(yellow, fx, h - fy), (p["frame"], p["track_id"])
    code, _, err = cli("plot", "t.h5", "-o", "t.png")
    assert code == 0, err


def test_plot_outlines_the_excluded_pixels(plotted):
    """A run's ``exclude`` rectangle is outlined in the left panel where it lies."""
    import json

    import h5py

    from irdetect.io import open_sequence, read_results
    from irdetect.plot import PLOT_COLOURS, plot_results, write_figure

    folder, _ = plotted
    with h5py.File(folder / "res.h5", "r+") as f:
        f.attrs["config"] = json.dumps({"exclude": ["4,40,40,58"]})
    with open_sequence(folder / "seq.h5") as src:
        fig = plot_results(read_results(folder / "res.h5"), src, scale=4)
    write_figure(folder / "x.png", fig)
    fig.canvas.draw()
    img = cv2.cvtColor(cv2.imread(str(folder / "x.png")), cv2.COLOR_BGR2RGB)
    blue = _colour_mask(img, PLOT_COLOURS["excluded"], tol=40)
    ax = fig.axes[0]

    def at(x, y):
        """Image (column, row) of data point (x, y): matplotlib counts rows from below."""
        px = ax.transData.transform([[x, y]])[0]
        return px[0], img.shape[0] - px[1]

    # the outline runs through the rectangle's corner and edge pixels, not its middle
    assert all(_near(blue, *at(x, y)) for x, y in ((4, 40), (39, 40), (4, 57), (22, 57)))
    assert not _near(blue, *at(22, 20), r=4)
    assert "excluded (nothing reported)" in [t.get_text() for t in ax.get_legend().get_texts()]
