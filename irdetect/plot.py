"""One figure of a results file: tracks over the max projection, and the Hough accumulator.

Left panel: the per-pixel maximum over the whole sequence (raw frames, or the suppressed
frames, where a moving dim point leaves a visible streak), with the confirmed detections
(open circles coloured by window), the initiated tracks (estimated path from
``frame_start`` to ``frame_end`` as an orange arrow with its id), frame-by-frame tracker
paths (yellow) and the truth (green open diamonds drawn over everything else), and a
legend.

Right panel: the Hough accumulator of the confirmed detections, recomputed as the
initiator (``irdetect.initiate``, method ``hough-sc``) builds it -- ``hough_grid`` with the
results' ``rho_step`` and ``n_theta``, ``hough_transform`` of all detections, the
candidate cells with at least T = ceil(vote_fraction x number of combined frames) votes
(white dots), and the centres ``subtractive_cluster`` picks among them (cyan circles);
the (rho, theta) of the tracks in the file are orange crosses. Axes in rho (px) and theta
(degrees), a colour bar of the votes. Cells crowding around each line is the "peak
clustering" of Zhang, Su & Ma (2010); one centre per crowd is its fix.

Drawn with matplotlib (the ``plot`` extra: ``pip install irdetect[plot]``) on the Agg
canvas, no display needed; the colours are those of the video overlay
(``irdetect.render.COLOURS``, docs/video.md).
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np

from irdetect.cluster import subtractive_cluster
from irdetect.errors import InputError
from irdetect.hough import hough_grid, hough_transform
from irdetect.initiate.base import vote_threshold
from irdetect.render import (COLOURS, WINDOW_PALETTE, Overlay, check_results_match,
                             display_limits, run_exclusions, stretch)

log = logging.getLogger(__name__)

#: initiator parameters the accumulator picture needs, with the initiator's defaults
HOUGH_DEFAULTS = dict(n_theta=90, rho_step=2.0, vote_fraction=0.6, radius_rho=3.0,
                      radius_theta=4.0, squash=1.25, accept_ratio=0.5, reject_ratio=0.15,
                      tile=0.0, sigma=1.5, vote_band=0.0)   # results before vote_band: 0



def rgb(bgr) -> tuple[float, float, float]:
    """A BGR 0-255 colour of ``irdetect.render`` as matplotlib's RGB 0-1."""
    b, g, r = bgr
    return (r / 255, g / 255, b / 255)


#: the figure's colours (matplotlib RGB), the video's (``irdetect.render.COLOURS``)
PLOT_COLOURS = {
    "track": rgb(COLOURS["track"]),              # orange
    "tracker": rgb(COLOURS["tracker"]),          # yellow
    "truth": rgb(COLOURS["truth"]),              # green
    "excluded": rgb(COLOURS["excluded"]),        # dim blue
    "windows": [rgb(c) for c in WINDOW_PALETTE],  # cyan, magenta, blue, pink by window
    "cell": (1.0, 1.0, 1.0),                     # white
    "centre": (0.0, 1.0, 1.0),                   # cyan
}
#: output suffix -> matplotlib's format
IMAGE_FORMATS = {".png": "png", ".jpg": "jpeg", ".jpeg": "jpeg", ".tif": "tiff",
                 ".tiff": "tiff", ".pdf": "pdf", ".svg": "svg"}


def max_projection(source, *, suppressed: bool = False, config: dict | None = None,
                   block: int = 64, progress: bool = False) -> np.ndarray:
    """Per-pixel maximum over a sequence, read ``block`` frames at a time.

    Parameters
    ----------
    source : irdetect.io.FrameSource
        Frames of shape (H, W).
    suppressed : bool
        Project the clutter-suppressed frames (``irdetect.suppress.suppress`` with the
        ``suppress`` section of ``config``) instead of the raw ones.
    config : dict, optional
        The resolved configuration of a results file (``Results.config``).

    Returns
    -------
    ndarray of shape (H, W), float32
    """
    from tqdm import tqdm

    from irdetect.render import _call_with

    params = dict((config or {}).get("suppress", {}))
    history = int(params.get("history", 0)) if params.get("method") == "temporal" else 0
    out = None
    tail = None
    bar = tqdm(total=len(source), unit="frame", desc="projection", disable=not progress,
               leave=False)
    for _, frames in source.windows(block):
        data = np.asarray(frames, np.float32)
        if suppressed:
            from irdetect.suppress import suppress

            res = _call_with(suppress, params, frames=data, previous=tail if history else None)
            if history:
                tail = data[-history:] if tail is None else \
                    np.concatenate([tail, data])[-history:]
            data = res
        m = data.max(axis=0)
        out = m if out is None else np.maximum(out, m)
        bar.update(len(frames))
    bar.close()
    return out


def accumulator(detections, params: dict | None = None) -> dict:
    """The initiator's Hough accumulator of all detections, its candidate cells and the
    subtractive-clustering centres among them.

    Parameters
    ----------
    detections : structured ndarray
        ``irdetect.tables.DETECTION`` rows (x = column, y = row, px).
    params : dict, optional
        Initiation parameters (the ``initiate`` section of a results file's config);
        missing ones take ``HOUGH_DEFAULTS``.

    Returns
    -------
    dict
        ``acc`` (n_rho, n_theta) votes, ``grid`` (HoughGrid), ``threshold`` T,
        ``cells`` (K, 2) int rho/theta indices of the cells with acc >= T,
        ``centres`` (C, 2) float (rho, theta) of the cluster centres.

    Notes
    -----
    The initiator works on the whole plane unless ``tile`` > 0; with tiles it builds one
    accumulator per overlapping tile. This picture is always the whole-plane accumulator
    (one picture, not dozens), so with tiles its cells differ from the initiator's.
    """
    p = {**HOUGH_DEFAULTS, **{k: v for k, v in (params or {}).items() if k in HOUGH_DEFAULTS}}
    x = np.asarray(detections["x"], float)
    y = np.asarray(detections["y"], float)
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    n_scans = np.unique(np.asarray(detections["combined_frame"])[ok]).size
    rmax = (float(np.hypot(x, y).max()) if x.size else 1.0) + p["rho_step"]
    grid = hough_grid(rho_max=rmax, rho_step=p["rho_step"], n_theta=int(p["n_theta"]))
    acc = hough_transform(x, y, grid=grid, band=p["vote_band"] * p["sigma"])[0]
    thr = vote_threshold(p["vote_fraction"], n_scans)
    cells = np.argwhere(acc >= thr) if x.size else np.zeros((0, 2), np.int64)
    centres = np.zeros((0, 2))
    if len(cells) and n_scans >= 2:
        rt = np.column_stack([grid.rho_centres[cells[:, 0]], grid.theta_centres[cells[:, 1]]])
        cl = subtractive_cluster(
            rt, radii=[p["radius_rho"] * grid.drho / (grid.rho_max - grid.rho_min),
                       p["radius_theta"] * grid.dtheta / math.pi],
            squash=p["squash"], accept_ratio=p["accept_ratio"],
            reject_ratio=p["reject_ratio"],
            bounds=[[grid.rho_min, 0.0], [grid.rho_max, math.pi]], wrap_lines=True)
        centres = cl.centres
    return {"acc": acc, "grid": grid, "threshold": thr, "cells": cells, "centres": centres,
            "n_scans": n_scans, "tile": p["tile"]}


def require_matplotlib():
    """matplotlib's Figure and Agg canvas, or an InputError with the install hint."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise InputError("drawing the figure needs matplotlib: pip install irdetect[plot]") \
            from None
    logging.getLogger("matplotlib").setLevel(logging.WARNING)   # no font-cache chatter
    return Figure, FigureCanvasAgg


def draw_tracks(ax, background, shape, overlay: Overlay, *, gamma: float = 1.0) -> None:
    """The left panel on matplotlib axes ``ax``: detections, tracks, tracker paths and
    truth over ``background``, with a legend.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
    background : ndarray of shape (H, W) or None
        The max projection (stretched for display here); None gives a dark background.
    shape : (H, W)
    overlay : irdetect.render.Overlay
        The tables; points are (x, y) = (column, row) px, pixel centres at integers.
    """
    h, w = shape
    if background is None:
        grey = np.full((h, w), 16, np.uint8)
    else:
        lo, hi = display_limits(background, low=1.0, high=99.9)
        grey = stretch(background, limits=(lo, hi), gamma=gamma)
    ax.imshow(grey, cmap="gray", vmin=0, vmax=255, interpolation="nearest",
              extent=(-0.5, w - 0.5, h - 0.5, -0.5))
    for i, c in enumerate(overlay.excluded):
        ring = np.vstack([c[:, 0], c[:1, 0]])
        ax.plot(ring[:, 0], ring[:, 1], color=PLOT_COLOURS["excluded"], lw=1.0, zorder=2,
                label="excluded (nothing reported)" if i == 0 else None)
    det = overlay.detections
    windows = PLOT_COLOURS["windows"]
    colours = [windows[int(k) % len(windows)] for k in det["combined_frame"]]
    ax.scatter(det["x"], det["y"], s=40, facecolors="none", edgecolors=colours,
               linewidths=1.0, zorder=3,
               label="detection (colour: window)" if len(det) else None)
    tp = overlay.track_points
    for i, tid in enumerate(np.unique(tp["track_id"])):
        rows = tp[tp["track_id"] == tid]
        ax.plot(rows["x"], rows["y"], color=PLOT_COLOURS["tracker"], lw=1.0, zorder=4,
                label="tracker path" if i == 0 else None)
        ax.annotate(f"#{int(tid)}", (rows["x"][-1], rows["y"][-1]), xytext=(4, -10),
                    textcoords="offset points", color=PLOT_COLOURS["tracker"], fontsize=8,
                    zorder=6)
    drawn = 0
    for row in overlay.tracks:
        if not (np.isfinite(row["x0"]) and np.isfinite(row["vx"])):
            continue
        frames = np.arange(int(row["frame_start"]), int(row["frame_end"]) + 1)
        xs, ys = overlay.track_at(row, frames)
        ax.plot(xs, ys, color=PLOT_COLOURS["track"], lw=1.6, zorder=5,
                label="initiated track" if drawn == 0 else None)
        if len(xs) > 1:
            ax.annotate("", xy=(xs[-1], ys[-1]), xytext=(xs[-2], ys[-2]), zorder=5,
                        arrowprops=dict(arrowstyle="-|>", color=PLOT_COLOURS["track"],
                                        lw=1.6, mutation_scale=12))
        ax.annotate(f"T{int(row['track_id'])}", (xs[-1], ys[-1]), xytext=(4, 4),
                    textcoords="offset points", color=PLOT_COLOURS["track"], fontsize=8,
                    zorder=6)
        drawn += 1
    truth = overlay.truth
    for i, tid in enumerate(np.unique(truth["target"])):
        rows = truth[truth["target"] == tid]
        step = max(1, len(rows) // 24)            # about two dozen markers per target
        ax.plot(rows["x"][::step], rows["y"][::step], ls="none", marker="D", ms=4,
                mfc="none", mec=PLOT_COLOURS["truth"], mew=1.2, zorder=7,
                label="truth" if i == 0 else None)
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.set_xlabel("x (px, column)")
    ax.set_ylabel("y (px, row)")
    handles, labels = ax.get_legend_handles_labels()
    if handles:
        ax.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2,
                  fontsize=8, frameon=False)


def draw_hough(ax, hough: dict, tracks: np.ndarray):
    """The right panel on ``ax``: the accumulator (colour = votes, square-root scale) over
    theta (degrees) across and rho (px) down, cropped to the rows that hold votes; the
    candidate cells, the cluster centres and the tracks' (rho, theta). Returns the image
    (for a colour bar)."""
    from matplotlib.colors import PowerNorm

    acc, grid = hough["acc"], hough["grid"]
    n_rho = acc.shape[0]
    rows = np.flatnonzero(acc.any(axis=1))
    if rows.size:
        pad = max(2, int(0.05 * (rows[-1] - rows[0] + 1)))
        j0, j1 = max(0, rows[0] - pad), min(n_rho, rows[-1] + pad + 1)
    else:
        j0, j1 = 0, n_rho
    rho_lo, rho_hi = grid.rho_min + j0 * grid.drho, grid.rho_min + j1 * grid.drho
    peak = float(acc.max()) if acc.size else 0.0
    image = ax.imshow(acc[j0:j1], cmap="inferno", aspect="auto", interpolation="nearest",
                      norm=PowerNorm(0.5, vmin=0, vmax=max(peak, 1.0)),
                      extent=(0.0, 180.0, rho_hi, rho_lo))
    cells = hough["cells"]
    ax.scatter(np.degrees(grid.theta_centres[cells[:, 1]]) if len(cells) else [],
               grid.rho_centres[cells[:, 0]] if len(cells) else [], s=4,
               color=PLOT_COLOURS["cell"], zorder=3,
               label=f"{len(cells)} cells >= {hough['threshold']:g} votes")
    centres = hough["centres"]
    ax.scatter(np.degrees(centres[:, 1]), centres[:, 0], s=120, facecolors="none",
               edgecolors=PLOT_COLOURS["centre"], linewidths=1.4, zorder=4,
               label=f"{len(centres)} cluster centres")
    ok = np.isfinite(tracks["rho"]) & np.isfinite(tracks["theta"])
    ax.scatter(np.degrees(tracks["theta"][ok]), tracks["rho"][ok], marker="x", s=60,
               color=PLOT_COLOURS["track"], linewidths=2.0, zorder=5,
               label=f"{int(ok.sum())} tracks (rho, theta)")
    ax.set_xlim(0.0, 180.0)
    ax.set_ylim(rho_hi, rho_lo)
    ax.set_xlabel("theta (degrees)")
    ax.set_ylabel("rho (px)")
    title = f"Hough accumulator of the detections ({hough['n_scans']} combined frames)"
    if hough.get("tile"):
        title += f"\n(whole plane; the initiator used {hough['tile']:g} px tiles)"
    ax.set_title(title, fontsize=9)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2, fontsize=8,
              frameon=False)
    return image


def plot_results(results, source=None, *, suppressed: bool = True, truth=None,
                 scale: float | None = None, gamma: float = 1.0, progress: bool = False):
    """The figure of a results file: tracks over the max projection | Hough accumulator
    (``irdetect process``), or the tracker's paths over the max projection alone
    (``irdetect track``).

    Parameters
    ----------
    results : irdetect.io.Results
        Read with ``irdetect.io.read_results`` (structured arrays).
    source : irdetect.io.FrameSource, optional
        The sequence, for the max projection (checked against the results); without it
        the tracks are drawn over a dark background of the size in the results' attributes.
    suppressed : bool
        Project the suppressed frames (streaks of moving points) rather than the raw ones.
    truth : structured ndarray, optional
        ``irdetect.tables.TRUTH`` rows (x = column, y = row, px), drawn as green diamonds.
    scale : float, optional
        Figure pixels per source pixel of the left panel (default: enough for 480 px
        width, at most 4).

    Returns
    -------
    matplotlib.figure.Figure
        On an Agg canvas; ``fig.axes[0]`` is the tracks panel (data coordinates x, y px),
        ``fig.axes[1]`` the accumulator (theta in degrees, rho in px; not for the results
        of ``irdetect track``). Write it with ``write_figure``.

    Raises
    ------
    InputError
        Neither /detections nor /track_points, results of another sequence, or
        matplotlib missing.
    """
    Figure, Canvas = require_matplotlib()
    found = results.tables
    tracker = "detections" not in found and "track_points" in found
    if "detections" not in found and not tracker:
        raise InputError("holds neither /detections nor /track_points: not the results of "
                         "irdetect process or track", results.path)
    if source is not None:
        check_results_match(results, source.shape, sequence_name=Path(source.path).name)
        h, w = source.shape[1:]
    else:
        a = results.attrs
        if "frame_height" not in a or "frame_width" not in a:
            raise InputError("the frame size is not in the results' attributes; give the "
                             "sequence with --sequence", results.path)
        h, w = int(a["frame_height"]), int(a["frame_width"])
    if scale is None:
        scale = 1.0 if w >= 480 else float(min(4, int(np.ceil(480 / w))))
    # the tracker's /tracks summarise its paths: the paths themselves are drawn
    overlay = Overlay.from_tables({k: v for k, v in found.items()
                                   if not (tracker and k == "tracks")}, truth,
                                  run_exclusions(results.config, (h, w)))
    background, what = None, "no sequence: dark background"
    if source is not None:
        background = max_projection(source, suppressed=suppressed, config=results.config,
                                    progress=progress)
        what = "max of suppressed frames" if suppressed else "max of raw frames"
    dpi = 100.0
    panel_w, panel_h = max(3.0, scale * w / dpi), max(2.5, scale * h / dpi)
    if tracker:
        fig = Figure(figsize=(panel_w + 1.0, panel_h + 1.9), dpi=dpi, layout="constrained")
        Canvas(fig)
        ax = fig.subplots()
        draw_tracks(ax, background, (h, w), overlay, gamma=gamma)
        n = len(np.unique(overlay.track_points["track_id"]))
        ax.set_title(f"{what}; {n} tracker tracks", fontsize=9)
        return fig
    fig = Figure(figsize=(2 * panel_w + 2.6, panel_h + 1.9), dpi=dpi, layout="constrained")
    Canvas(fig)
    left, right = fig.subplots(1, 2, width_ratios=[panel_w, panel_w + 0.6])
    draw_tracks(left, background, (h, w), overlay, gamma=gamma)
    left.set_title(f"{what}; {len(overlay.detections)} detections, "
                   f"{len(overlay.tracks)} tracks", fontsize=9)
    hough = accumulator(found["detections"], results.config.get("initiate"))
    image = draw_hough(right, hough, overlay.tracks)
    fig.colorbar(image, ax=right, label="votes (detections on the cell's line)")
    return fig


def plot_roc(curves: dict, *, title: str = ""):
    """A figure of ROC curves: Pd against false detections per frame (log axis).

    Parameters
    ----------
    curves : dict
        ``{label: roc}``, each ``roc`` a dict of ``irdetect.metrics.detection.roc`` (its
        ``pd``, ``false_per_frame`` and ``auc``).
    title : str
        The axes' title.
    """
    Figure, _ = require_matplotlib()
    fig = Figure(figsize=(6.0, 4.5), dpi=100)
    ax = fig.add_subplot()
    for label, c in curves.items():
        f = np.asarray(c["false_per_frame"], float)
        pd = np.asarray(c["pd"], float)
        order = np.argsort(f, kind="stable")
        # rates of 0 drawn at the axis' floor so the curve starts where it does
        ax.step(np.maximum(f[order], 1e-3), pd[order], where="post",
                label=f"{label} (area {c['auc']:.2f})")
    ax.axvline(0.1, color="0.6", lw=0.8, ls="--")
    ax.set_xscale("log")
    ax.set_xlim(1e-3, None)
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("false detections per frame (0 drawn at 0.001)")
    ax.set_ylabel("Pd (target-windows)")
    ax.set_title(title or "ROC over the detections' local SNR")
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    return fig


def write_figure(path, fig, *, force: bool = False, inputs=()) -> Path:
    """Write a matplotlib figure atomically (``irdetect.io.atomic_output``: a temporary
    beside it, then a rename; mode 0666 less the umask); never over one of ``inputs``.

    Raises
    ------
    InputError
        Bad path (see ``irdetect.io.check_output_path``) or an unknown image type.
    """
    from irdetect.io import atomic_output, check_output_path

    path = check_output_path(path, force, inputs)
    suffix = path.suffix.lower()
    if suffix not in IMAGE_FORMATS:
        raise InputError(f"unknown image type {path.suffix!r} (use .png, .jpg, .tif, .pdf "
                         "or .svg)", path)
    with atomic_output(path, force=force, inputs=inputs, suffix=suffix) as tmp:
        fig.savefig(tmp, format=IMAGE_FORMATS[suffix])
    return path
