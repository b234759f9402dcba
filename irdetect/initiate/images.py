"""Track initiation on the confirmed detections of an image sequence, and the tracks'
positions (through a moving camera).

Each detection is one measurement at time (frame_start + frame_end) / 2 in the "scan" given
by its combined frame; coordinates x = column, y = row in pixels, time in frames.
"""

from __future__ import annotations

import numpy as np

from irdetect import tables
from irdetect.initiate.base import DEFAULTS
from irdetect.initiate.common import merge_windows, scan_windows
from irdetect.initiate.contract import initiate_points


def initiate_detections(detections, *, method: str = DEFAULTS["method"],
                        n_theta: int = DEFAULTS["n_theta"],
                        rho_step: float = DEFAULTS["rho_step"], tile: float = DEFAULTS["tile"],
                        vote_fraction: float = DEFAULTS["vote_fraction"],
                        vote_band: float = 1.0,
                        parallel_fraction: float = DEFAULTS["parallel_fraction"],
                        q1: float = DEFAULTS["q1"], q2: float = DEFAULTS["q2"],
                        sigma: float = DEFAULTS["sigma"],
                        sigma_range: float = DEFAULTS["sigma_range"],
                        sigma_azimuth: float = DEFAULTS["sigma_azimuth"],
                        radius_rho: float = DEFAULTS["radius_rho"],
                        radius_theta: float = DEFAULTS["radius_theta"],
                        squash: float = DEFAULTS["squash"],
                        accept_ratio: float = DEFAULTS["accept_ratio"],
                        reject_ratio: float = DEFAULTS["reject_ratio"],
                        merge_peaks: bool = DEFAULTS["merge_peaks"],
                        nms_size: int = DEFAULTS["nms_size"], verify: bool = DEFAULTS["verify"],
                        gate: float = DEFAULTS["gate"], v_min: float = DEFAULTS["v_min"],
                        v_max: float = DEFAULTS["v_max"], min_hits: float = DEFAULTS["min_hits"],
                        confirm_m: int = DEFAULTS["confirm_m"],
                        confirm_n: int = DEFAULTS["confirm_n"],
                        fit_confidence: float = DEFAULTS["fit_confidence"],
                        false_tracks: float = DEFAULTS["false_tracks"],
                        window: int = 10) -> np.ndarray:
    """Initiate tracks from the confirmed detections of an image sequence.

    Each detection is one measurement at time (frame_start + frame_end) / 2, in the "scan"
    given by its combined frame. Parameters are those of ``initiate_points`` (units: pixels,
    frames; ``sigma`` is the detection position error in px, ``v_min``/``v_max`` px/frame,
    0 = no bound).

    Parameters
    ----------
    detections : structured ndarray
        ``irdetect.tables.DETECTION`` rows (x = column, y = row).
    vote_band : float
        Half-width of each detection's Hough vote in sigmas (``hough_transform``'s
        ``band``). 1 here, against the scans' 0 (the papers' single cell): a target's 3-4
        detections of a short sequence within their errors of one line fall in one 2-px
        cell only when the cell edges allow, and a target that turns holds a line over 3
        combined frames only to about a sigma.
    window : int
        Combined frames per initiation window (Zhang et al.'s M scans; 0 = the whole
        sequence in one window). Windows overlap by half (``scan_windows`` with step
        ``window // 2``); a sequence of at most ``window`` combined frames is one window.
        Tracks of consecutive windows that fit one constant velocity together are one
        target and are merged (``merge_windows``).

    Returns
    -------
    structured ndarray
        ``irdetect.tables.TRACK`` rows: rho, theta (rho = x cos(theta) + y sin(theta),
        theta in [0, pi)), vx, vy in px/frame, frame_start / frame_end of the members'
        windows, n_points, score, x0, y0 at frame_start. Empty (with its fields) when
        there are fewer than two combined frames or nothing forms a track.

    Examples
    --------
    >>> import numpy as np
    >>> from irdetect import tables
    >>> k = np.arange(8)
    >>> det = tables.from_columns(tables.DETECTION, x=10 + 12.0 * k, y=20 + 6.0 * k,
    ...     frame_start=12 * k, frame_end=12 * k + 11, combined_frame=k)
    >>> tr = initiate_detections(det)
    >>> len(tr), round(float(tr["vx"][0]), 2), round(float(tr["vy"][0]), 2)
    (1, 1.0, 0.5)
    """
    params = {k: v for k, v in locals().items() if k in DEFAULTS}
    det = np.asarray(detections)
    for name in ("x", "y", "frame_start", "frame_end", "combined_frame"):
        if det.dtype.names is None or name not in det.dtype.names:
            raise ValueError(f"detections lack the field {name!r}")
    if int(window) != window or window < 0 or window == 1:
        raise ValueError(f"window must be 0 or an integer >= 2, got {window!r}")
    t = 0.5 * (det["frame_start"] + det["frame_end"]).astype(float)
    scan = det["combined_frame"]
    spans = (scan_windows(scan, window=int(window), step=max(1, int(window) // 2))
             if window else [])
    if len(spans) <= 1:
        rows, members = initiate_points(det["x"], det["y"], t, scan, **params)
    else:
        found = []
        for a, b in spans:
            sel = np.flatnonzero((scan >= a) & (scan <= b))
            r, m = initiate_points(det["x"][sel], det["y"][sel], t[sel], scan[sel], **params)
            found += [(row, sel[mm]) for row, mm in zip(r, m)]
        rows, members = merge_windows(found, det["x"], det["y"], t, scan,
                                      sigma=sigma, fit_confidence=fit_confidence)
    out = tables.from_columns(tables.TRACK, n=len(rows))
    if not len(rows):
        return out
    out["track_id"] = np.arange(len(rows))
    for name in ("rho", "theta", "vx", "vy", "n_points", "score"):
        out[name] = rows[name]
    for i, m in enumerate(members):
        out["frame_start"][i] = det["frame_start"][m].min()
        out["frame_end"][i] = det["frame_end"][m].max()
    shift = out["frame_start"] - rows["t_start"]
    out["x0"] = rows["x0"] + rows["vx"] * shift
    out["y0"] = rows["y0"] + rows["vy"] * shift
    return out


def camera_at(camera, frames) -> np.ndarray:
    """The camera's offsets (n, 2) at (fractional) ``frames`` (n,): ``camera`` is a
    ``tables.CAMERA`` table or an array (T, 2) of the offsets of frames 0..T-1; linear
    between frames, the nearest end outside them."""
    c = np.asarray(camera)
    if c.dtype.names is not None:
        f, cx, cy = c["frame"].astype(float), c["dx"], c["dy"]
    else:
        c = c.reshape(-1, 2)
        f, cx, cy = np.arange(len(c), dtype=float), c[:, 0], c[:, 1]
    t = np.asarray(frames, float)
    if len(f) == 0:
        return np.zeros((len(t), 2))
    return np.column_stack([np.interp(t, f, cx), np.interp(t, f, cy)])


def track_positions(tracks, frames, camera=None) -> np.ndarray:
    """Image positions (x, y) px of tracks in frames: every track in every frame.

    Parameters
    ----------
    tracks : structured ndarray
        ``tables.TRACK`` rows (n).
    frames : array_like of shape (m,)
        Frame indices.
    camera : CAMERA table or ndarray of shape (T, 2), optional
        The camera's offsets (``/camera`` of the results file); needed for ``scene``
        tracks, whose positions follow the camera: (x0, y0) + (vx, vy) (f - frame_start)
        + C_f - C_frame_start.

    Returns
    -------
    ndarray of shape (n, m, 2)
        Positions where the tracks' lines put them (also outside their frame spans).
    """
    return positions_at(np.asarray(tracks)[:, None], np.asarray(frames, float)[None, :], camera)


def positions_at(tracks, frames, camera=None) -> np.ndarray:
    """Image positions (x, y) px of tracks in frames, element by element: ``tracks`` (a
    ``tables.TRACK`` array) and ``frames`` broadcast against each other, as
    ``track_positions``'s (n, 1) and (1, m) or a list of (track, frame) pairs (k,) and (k,).

    Returns
    -------
    ndarray of the broadcast shape + (2,)
    """
    tr = np.asarray(tracks)
    f = np.asarray(frames, float)
    dt = f - tr["frame_start"]
    pos = np.stack([tr["x0"] + tr["vx"] * dt, tr["y0"] + tr["vy"] * dt], axis=-1)
    scene = tr["scene"] if "scene" in (tr.dtype.names or ()) else np.zeros(tr.shape, bool)
    scene = np.broadcast_to(scene, dt.shape)
    if scene.any():
        if camera is None:
            raise ValueError("scene tracks need the camera's offsets (/camera)")
        move = _camera_at_nd(camera, f) - _camera_at_nd(camera, tr["frame_start"])
        pos += np.where(scene[..., None], move, 0.0)
    return pos


def _camera_at_nd(camera, frames) -> np.ndarray:
    """``camera_at`` for frames of any shape: shape + (2,)."""
    f = np.asarray(frames, float)
    return camera_at(camera, f.ravel()).reshape(f.shape + (2,))
