"""One picture of an ``irdetect initiate`` result on scans: the measurements (grey, brighter
for later scans), the true paths (green) and the initiated tracks (one colour each, from
their first to their last scan), in the file's units with y up."""

from __future__ import annotations

import json

import cv2
import numpy as np

from irdetect.metrics.initiation import scan_tracks_of


def plot_scan_results(results, *, size: int = 900) -> np.ndarray:
    """An image (size, size, 3) uint8 (BGR) of a scans result.

    Parameters
    ----------
    results : irdetect.io.Results
        With scan ``/tracks`` (or ``/scan_tracks``), ``/scans`` and optionally
        ``/scan_truth``; track positions at the scans' times from ``scan_times``.
    size : int
        Picture side in px.
    """
    tracks = scan_tracks_of(results)
    scans = results["scans"] if "scans" in results else np.zeros(0, tracks.dtype)
    truth = results["scan_truth"] if "scan_truth" in results else None
    xs = np.r_[scans["x"], truth["x"] if truth is not None else []]
    ys = np.r_[scans["y"], truth["y"] if truth is not None else []]
    x0, x1 = (xs.min(), xs.max()) if xs.size else (0.0, 1.0)
    y0, y1 = (ys.min(), ys.max()) if ys.size else (0.0, 1.0)
    span = max(x1 - x0, y1 - y0, 1e-12)
    m = 30
    k = (size - 2 * m) / span

    def px(x, y):
        return np.column_stack([m + (np.asarray(x) - x0) * k,
                                size - m - (np.asarray(y) - y0) * k]).round().astype(np.int32)

    img = np.zeros((size, size, 3), np.uint8)
    if scans.size:
        u, idx = np.unique(scans["scan"], return_inverse=True)
        grey = (60 + 140 * idx / max(1, u.size - 1)).astype(np.uint8)
        p = px(scans["x"], scans["y"])
        ok = (p[:, 0] >= 0) & (p[:, 0] < size) & (p[:, 1] >= 0) & (p[:, 1] < size)
        img[p[ok, 1], p[ok, 0]] = grey[ok, None]
    if truth is not None:
        for tgt in np.unique(truth["target"]):
            r = truth[truth["target"] == tgt]
            r = r[np.argsort(r["scan"])]
            cv2.polylines(img, [px(r["x"], r["y"])], False, (0, 200, 0), 1, cv2.LINE_AA)
    times = {int(a): float(b) for a, b in json.loads(results.attrs.get("scan_times", "{}")).items()}
    rng = np.random.default_rng(0)
    for tr in tracks:
        t0, t1 = times.get(int(tr["scan_start"]), 0.0), times.get(int(tr["scan_end"]), 0.0)
        ends = px([tr["x0"], tr["x0"] + tr["vx"] * (t1 - t0)],
                  [tr["y0"], tr["y0"] + tr["vy"] * (t1 - t0)])
        colour = tuple(int(c) for c in rng.integers(80, 256, 3))
        cv2.line(img, tuple(ends[0]), tuple(ends[1]), colour, 2, cv2.LINE_AA)
        cv2.circle(img, tuple(ends[1]), 3, colour, -1)
    cv2.putText(img, f"{len(tracks)} tracks, {len(scans)} measurements; extent {span:.4g} "
                "(file units)", (m, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1,
                cv2.LINE_AA)
    return img
