"""One picture of a results file: tracks over the max projection, and the Hough accumulator.

Left panel: the per-pixel maximum over the whole sequence (raw frames, or the suppressed
frames, where a moving dim point leaves a visible streak), with the confirmed detections
(circles coloured by window), the initiated tracks (estimated path from ``frame_start``
to ``frame_end`` as an arrow with its id), frame-by-frame tracker paths and the truth.

Right panel: the Hough accumulator of the confirmed detections, recomputed as the
initiator (``irdetect.initiate``, method ``hough-sc``) builds it -- ``hough_grid`` with the
results' ``rho_step`` and ``n_theta``, ``hough_transform`` of all detections, the
candidate cells with at least T = ceil(vote_fraction x number of combined frames) votes
(white dots), and the centres ``subtractive_cluster`` picks among them (cyan circles);
the (rho, theta) of the tracks in the file are green crosses. Cells crowding around each
line is the "peak clustering" of Zhang, Su & Ma (2010); one centre per crowd is its fix.
Drawing is OpenCV only (no matplotlib).
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import cv2
import numpy as np

from irdetect.cluster import subtractive_cluster
from irdetect.errors import InputError
from irdetect.hough import hough_grid, hough_transform
from irdetect.render import (COLOURS, Overlay, _FONT, _to_px, check_results_match,
                             display_limits, put_text, scale_image, stretch, window_colour)

log = logging.getLogger(__name__)

#: initiator parameters the accumulator picture needs, with the initiator's defaults
HOUGH_DEFAULTS = dict(n_theta=90, rho_step=2.0, vote_fraction=0.6, radius_rho=3.0,
                      radius_theta=4.0, squash=1.25, accept_ratio=0.5, reject_ratio=0.15,
                      tile=0.0)
CENTRE_COLOUR = (255, 255, 0)       # cyan
CELL_COLOUR = (255, 255, 255)


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
    acc = hough_transform(x, y, grid=grid)[0]
    thr = max(1.0, math.ceil(p["vote_fraction"] * n_scans - 1e-9))
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


def _put(image, text, org, scale, colour=(255, 255, 255)):
    put_text(image, text, org, scale, colour)


def tracks_panel(background: np.ndarray | None, shape, overlay: Overlay, *, scale: float,
                 title: str, gamma: float = 1.0) -> np.ndarray:
    """The left panel: tracks, detections, tracker paths and truth over ``background``.

    Parameters
    ----------
    background : ndarray of shape (H, W) or None
        The max projection (stretched for display here); None gives a dark background.
    shape : (H, W)
    """
    h, w = shape
    if background is None:
        grey = np.full((h, w), 16, np.uint8)
    else:
        lo, hi = display_limits(background, low=1.0, high=99.9)
        grey = stretch(background, limits=(lo, hi), gamma=gamma)
    img = scale_image(grey, scale)
    r = max(4, int(round(2.5 * scale)))
    _paths(img, overlay.truth, "target", COLOURS["truth"], scale)
    det = overlay.detections
    px, py = _to_px(det["x"], det["y"], scale)
    for x, y, k in zip(px, py, det["combined_frame"]):
        cv2.circle(img, (int(round(x)), int(round(y))), r, window_colour(k), 1, cv2.LINE_AA)
    _paths(img, overlay.track_points, "track_id", COLOURS["tracker"], scale)
    fs = 0.45 if scale >= 2 else 0.4
    for row in overlay.tracks:
        if not (np.isfinite(row["x0"]) and np.isfinite(row["vx"])):
            continue
        px_, py_ = overlay.track_at(row, [row["frame_start"], row["frame_end"]])
        (ax, ay) = _to_px(px_[0], py_[0], scale)
        (bx, by) = _to_px(px_[1], py_[1], scale)
        length = max(1.0, math.hypot(bx - ax, by - ay))
        cv2.arrowedLine(img, (int(round(ax)), int(round(ay))), (int(round(bx)), int(round(by))),
                        COLOURS["track"], max(1, int(scale // 2)), cv2.LINE_AA,
                        tipLength=min(0.3, 10.0 / length))
        _put(img, f"T{int(row['track_id'])}", (int(bx) + 4, int(by) - 4), fs, COLOURS["track"])
    _put(img, title, (6, 18), fs)
    return img


def hough_panel(hough: dict, tracks: np.ndarray, height: int) -> np.ndarray:
    """The right panel: the accumulator as a colour map (square root of the votes), rho
    down, theta across; the rho axis is cropped to the rows that hold votes."""
    acc, grid = hough["acc"], hough["grid"]
    n_rho, n_theta = acc.shape
    rows = np.flatnonzero(acc.any(axis=1))
    if rows.size:
        pad = max(2, int(0.05 * (rows[-1] - rows[0] + 1)))
        j0, j1 = max(0, rows[0] - pad), min(n_rho, rows[-1] + pad + 1)
    else:
        j0, j1 = 0, n_rho
    acc = acc[j0:j1]
    margin_l, margin_b, margin_t = 44, 34, 44
    ph = height - margin_b - margin_t
    pw = int(round(ph * 1.1))
    img = np.full((height, pw + margin_l + 10, 3), 24, np.uint8)
    peak = acc.max() if acc.size else 0.0
    norm = np.zeros(acc.shape, np.uint8) if peak <= 0 else \
        np.rint(255 * np.sqrt(acc / peak)).astype(np.uint8)
    cmap = cv2.applyColorMap(norm, cv2.COLORMAP_INFERNO)
    img[margin_t:margin_t + ph, margin_l:margin_l + pw] = cv2.resize(
        cmap, (pw, ph), interpolation=cv2.INTER_NEAREST)
    sy, sx = ph / (j1 - j0), pw / n_theta

    def cell_px(j, n):          # fractional cell indices (full grid) -> panel pixel
        return (int(round(margin_l + (n + 0.5) * sx)),
                int(round(margin_t + (j - j0 + 0.5) * sy)))

    for j, n in hough["cells"]:
        cv2.circle(img, cell_px(j, n), 1, CELL_COLOUR, -1)
    for rho, theta in hough["centres"]:
        j = (rho - grid.rho_min) / grid.drho - 0.5
        n = theta / grid.dtheta - 0.5
        cv2.circle(img, cell_px(j, n), 9, CENTRE_COLOUR, 1, cv2.LINE_AA)
    for row in tracks:
        if not (np.isfinite(row["rho"]) and np.isfinite(row["theta"])):
            continue
        j = (row["rho"] - grid.rho_min) / grid.drho - 0.5
        n = row["theta"] / grid.dtheta - 0.5
        cv2.drawMarker(img, cell_px(j, n), COLOURS["truth"], cv2.MARKER_TILTED_CROSS, 16, 2,
                       cv2.LINE_AA)
    fs = 0.4
    rho_lo = grid.rho_min + j0 * grid.drho
    rho_hi = grid.rho_min + j1 * grid.drho
    for frac in (0.0, 0.5, 1.0):
        x = int(round(margin_l + frac * (pw - 1)))
        cv2.line(img, (x, margin_t + ph), (x, margin_t + ph + 4), (200, 200, 200), 1)
        _put(img, f"{180 * frac:.0f}", (x - 8, margin_t + ph + 16), fs)
        y = int(round(margin_t + frac * (ph - 1)))
        cv2.line(img, (margin_l - 4, y), (margin_l, y), (200, 200, 200), 1)
        _put(img, f"{rho_lo + frac * (rho_hi - rho_lo):.0f}", (2, y + 4), fs)
    _put(img, "theta (deg)", (margin_l + pw // 2 - 40, height - 4), fs)
    _put(img, "rho", (4, margin_t - 8), fs)
    _put(img, f"Hough accumulator of the detections ({hough['n_scans']} combined frames)",
         (margin_l, 16), fs)
    _put(img, f"{len(hough['cells'])} cells >= {hough['threshold']:g} votes", (margin_l, 34),
         fs, CELL_COLOUR)
    x = margin_l + cv2.getTextSize(f"{len(hough['cells'])} cells >= "
                                   f"{hough['threshold']:g} votes", _FONT, fs, 1)[0][0] + 12
    _put(img, f"{len(hough['centres'])} cluster centres", (x, 34), fs, CENTRE_COLOUR)
    x += cv2.getTextSize(f"{len(hough['centres'])} cluster centres", _FONT, fs, 1)[0][0] + 12
    _put(img, f"{len(tracks)} tracks", (x, 34), fs, COLOURS["truth"])
    if hough.get("tile"):
        _put(img, f"(whole plane; the initiator used {hough['tile']:g} px tiles)",
             (margin_l, height - 20), fs)
    return img


def plot_results(results, source=None, *, suppressed: bool = True, truth=None,
                 scale: float | None = None, gamma: float = 1.0,
                 progress: bool = False) -> np.ndarray:
    """Draw the figure of a results file: tracks over the max projection | Hough accumulator.

    Parameters
    ----------
    results : irdetect.io.Results
    source : irdetect.io.FrameSource, optional
        The sequence, for the max projection (checked against the results); without it
        the tracks are drawn over a dark background of the size in the results' attributes.
    suppressed : bool
        Project the suppressed frames (streaks of moving points) rather than the raw ones.
    truth : structured ndarray, optional
        ``irdetect.tables.TRUTH`` rows, drawn as green paths.
    scale : float, optional
        Output pixels per source pixel (default: enough for 480 px width, at most 4).

    Returns
    -------
    ndarray of shape (h, w, 3) uint8 (BGR)
    """
    found = results.tables
    if "detections" not in found:
        raise InputError("holds no /detections: not the results of `irdetect process`",
                         results.path)
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
    overlay = Overlay.from_tables(found, truth)
    background, what = None, "no sequence: dark background"
    if source is not None:
        background = max_projection(source, suppressed=suppressed, config=results.config,
                                    progress=progress)
        what = "max of suppressed frames" if suppressed else "max of raw frames"
    left = tracks_panel(background, (h, w), overlay, scale=scale, gamma=gamma,
                        title=f"{what}; {len(overlay.detections)} detections, "
                        f"{len(overlay.tracks)} tracks")
    hough = accumulator(found["detections"], results.config.get("initiate"))
    right = hough_panel(hough, overlay.tracks, left.shape[0])
    gap = np.full((left.shape[0], 6, 3), 64, np.uint8)
    return np.hstack([left, gap, right])


def write_image(path, image: np.ndarray, *, force: bool = False, inputs=()) -> Path:
    """Write an image atomically (``irdetect.io.atomic_output``: a temporary beside it,
    then a rename).

    Raises
    ------
    InputError
        Bad path (see ``irdetect.io.check_output_path``) or a type OpenCV cannot write.
    """
    from irdetect.io import atomic_output, check_output_path

    path = check_output_path(path, force, inputs)
    suffix = path.suffix.lower()
    if suffix not in (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff"):
        raise InputError(f"unknown image type {path.suffix!r} (use .png, .jpg, .bmp or .tif)",
                         path)
    with atomic_output(path, force=force, inputs=inputs, suffix=suffix) as tmp:
        if not cv2.imwrite(tmp, image):
            raise InputError("OpenCV could not write the image (disk full?)", path)
    return path


def _paths(img, table, key, colour, scale) -> None:
    """Draw one polyline per value of ``table[key]`` through its (x, y) rows."""
    for value in np.unique(table[key]):
        rows = table[table[key] == value]
        px, py = _to_px(rows["x"], rows["y"], scale)
        cv2.polylines(img, [np.round(np.column_stack([px, py])).astype(np.int32)], False,
                      colour, 1, cv2.LINE_AA)
