"""Record layouts of every table irdetect reads or writes, defined once.

Tables are numpy structured arrays; h5py stores them as compound datasets and
``pandas.DataFrame(arr)`` reads them. An empty table keeps its dtype (``empty(name)``).
Coordinates are pixels for image sequences (x = column, y = row) and metres for scans.
The names required by ``shared/design/formats.md`` are the first fields of each dtype;
everything after them is irdetect's own and documented in ``docs/format.md``.
"""

from __future__ import annotations

import numpy as np

#: Ground truth of an image sequence: one row per target per frame.
TRUTH = np.dtype([
    ("frame", "<i8"), ("target", "<i8"), ("x", "<f8"), ("y", "<f8"), ("amplitude", "<f8"),
])

#: Confirmed point detections, one row per target per combined frame (window). ``path``
#: says which path found it (``PATH_COMBINED``, ``PATH_FRAME`` or both bits); ``snr`` is the
#: score both paths share: the local SNR per frame, in matched-filter sigmas, along the
#: detection's track over the window; ``support`` the share of the window's frames with a
#: per-frame peak on that track (``irdetect.pipeline.fusion``); ``significance`` the
#: detection's value on its window's integrated map in units of that map's measured noise
#: (the combined-frame path; the per-frame path's rows: their ``snr``) and ``level`` the
#: window's operating point on it (``irdetect.operating``; -inf for the per-frame path's
#: rows, kept by that path's own test, and with ``operating.false_rate = 0``).
DETECTION = np.dtype([
    ("x", "<f8"), ("y", "<f8"), ("frame_start", "<i8"), ("frame_end", "<i8"),
    ("combined_frame", "<i8"), ("intensity", "<f8"), ("score", "<f8"),
    ("vx", "<f8"), ("vy", "<f8"), ("n_members", "<i4"),
    ("path", "<i1"), ("snr", "<f8"), ("support", "<f8"),
    ("significance", "<f8"), ("level", "<f8"),
])

#: ``path`` bits of detections and tracks: the combined-frame path, the per-frame path.
PATH_COMBINED = 1
PATH_FRAME = 2

#: Per-frame peaks (``irdetect.peaks``): frame, sub-pixel position (x = column, y = row,
#: px) and the local SNR in matched-filter sigmas.
FRAME_DETECTION = np.dtype([("frame", "<i8"), ("x", "<f8"), ("y", "<f8"), ("score", "<f8")])

#: Tracks of the per-frame path, one per window of frames (``irdetect.pipeline.perframe``):
#: position at the window's middle frame in the image (x, y px), image velocity (vx, vy
#: px/frame), scene velocity (svx, svy), hits, ``score`` the median local SNR of the hits,
#: ``expectation`` the chains as good that clutter of the local density would make,
#: ``moving`` (it moves against the scene by more than its position error) and ``kept``
#: (it passed every test of the operating point).
FRAME_TRACK = np.dtype([
    ("combined_frame", "<i8"), ("frame_start", "<i8"), ("frame_end", "<i8"),
    ("x", "<f8"), ("y", "<f8"), ("vx", "<f8"), ("vy", "<f8"), ("svx", "<f8"), ("svy", "<f8"),
    ("n_points", "<i8"), ("score", "<f8"), ("expectation", "<f8"), ("moving", "?"),
    ("kept", "?"),
])

#: Every fused point before correlation; ``confirmed`` marks those kept; ``band`` the
#: combined frame it was found in (0: the paper's, image coordinates; 1: the fast band's
#: merit that follows the scene; 2: the paper's merit following the scene, ``fast.scene``;
#: ``irdetect.pipeline``).
CANDIDATE = np.dtype([
    ("x", "<f8"), ("y", "<f8"), ("frame_start", "<i8"), ("frame_end", "<i8"),
    ("combined_frame", "<i8"), ("intensity", "<f8"), ("score", "<f8"),
    ("n_members", "<i4"), ("direction", "<i1"), ("confirmed", "?"), ("band", "<i1"),
])

#: 3-point segments over combined frames k, k+1, k+2 with velocity in px/frame.
SEGMENT = np.dtype([
    ("segment_id", "<i8"), ("combined_frame", "<i8"),
    ("x1", "<f8"), ("y1", "<f8"), ("x2", "<f8"), ("y2", "<f8"), ("x3", "<f8"), ("y3", "<f8"),
    ("vx", "<f8"), ("vy", "<f8"), ("score", "<f8"),
])

#: Initiated tracks of an image sequence (velocities in px/frame). rho, theta, x0, y0 are
#: in the image coordinates of ``frame_start``; a ``scene`` track is straight in the scene:
#: its position in frame f is (x0, y0) + (vx, vy) (f - frame_start) plus the camera's
#: motion since frame_start (``irdetect.initiate.track_positions``).
TRACK = np.dtype([
    ("track_id", "<i8"), ("rho", "<f8"), ("theta", "<f8"), ("vx", "<f8"), ("vy", "<f8"),
    ("frame_start", "<i8"), ("frame_end", "<i8"), ("n_points", "<i8"), ("score", "<f8"),
    ("x0", "<f8"), ("y0", "<f8"), ("scene", "?"), ("path", "<i1"),
])

#: The camera's image motion, one row per frame: a scene point at (x, y) in frame 0 is at
#: (x + dx, y + dy) in frame ``frame`` (px; ``irdetect.camera``); ``repeated``: the frame
#: repeats the frame before it exactly (``irdetect.repeats``).
CAMERA = np.dtype([("frame", "<i8"), ("dx", "<f8"), ("dy", "<f8"), ("gain", "<f8"),
                   ("level", "<f8"), ("repeated", "?")])

#: Radar-style measurements, one row per measurement; range/azimuth NaN when not polar.
SCAN = np.dtype([
    ("scan", "<i8"), ("time", "<f8"), ("x", "<f8"), ("y", "<f8"),
    ("range", "<f8"), ("azimuth", "<f8"),
])

#: Ground truth of a scans file.
SCAN_TRUTH = np.dtype([("scan", "<i8"), ("target", "<i8"), ("x", "<f8"), ("y", "<f8")])

#: Initiated tracks on scans (units of the scans, velocities per second).
SCAN_TRACK = np.dtype([
    ("track_id", "<i8"), ("rho", "<f8"), ("theta", "<f8"), ("vx", "<f8"), ("vy", "<f8"),
    ("scan_start", "<i8"), ("scan_end", "<i8"), ("n_points", "<i8"), ("score", "<f8"),
    ("x0", "<f8"), ("y0", "<f8"), ("window_start", "<i8"),
])

#: Frame-by-frame tracker output: one row per track per frame.
TRACK_POINT = np.dtype([
    ("frame", "<i8"), ("track_id", "<i8"), ("x", "<f8"), ("y", "<f8"),
    ("vx", "<f8"), ("vy", "<f8"), ("area", "<f8"), ("grey", "<f8"),
])

BY_NAME = {
    "truth": TRUTH, "detections": DETECTION, "candidates": CANDIDATE, "segments": SEGMENT,
    "tracks": TRACK, "combined_detections": DETECTION, "scans": SCAN, "scan_truth": SCAN_TRUTH, "scan_tracks": SCAN_TRACK,
    "track_points": TRACK_POINT, "camera": CAMERA, "frame_detections": FRAME_DETECTION,
    "frame_tracks": FRAME_TRACK,
}


def empty(dtype: np.dtype | str) -> np.ndarray:
    """An empty table of the given dtype (or name in ``BY_NAME``), fields kept."""
    return np.zeros(0, dtype=BY_NAME[dtype] if isinstance(dtype, str) else dtype)


def from_columns(dtype: np.dtype, n: int | None = None, **columns) -> np.ndarray:
    """Build a table from column arrays; missing columns are zero (NaN for floats).

    Parameters
    ----------
    dtype : numpy.dtype
        A structured dtype from this module.
    n : int, optional
        Row count when no column is given.
    **columns : array_like
        One 1-D array per field, all of the same length.
    """
    lengths = {len(np.atleast_1d(v)) for v in columns.values()}
    if len(lengths) > 1:
        raise ValueError(f"columns differ in length: {sorted(lengths)}")
    size = lengths.pop() if lengths else (n or 0)
    out = np.zeros(size, dtype=dtype)
    for name in dtype.names:
        if name in columns:
            out[name] = columns[name]
        elif out.dtype[name].kind == "f":
            out[name] = np.nan
    unknown = set(columns) - set(dtype.names)
    if unknown:
        raise ValueError(f"unknown columns {sorted(unknown)} for this table")
    return out
