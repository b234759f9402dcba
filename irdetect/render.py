"""Pictures for people: display contrast stretch and annotated frames (OpenCV drawing).

``stretch`` maps raw frames of any pixel type (8/16-bit, float) to 8-bit grey for display
with robust percentile limits and an optional gamma. ``Overlay`` indexes the tables of a
results file by frame; ``draw_overlay`` draws what the detector found at one frame:

* confirmed detections (``/detections``): circles, coloured by combined frame (window),
  drawn over every frame of the window they were found in;
* candidates (``/candidates`` not confirmed, optional): small crosses;
* initiated tracks (``/tracks``): the estimated straight path from ``frame_start`` to
  ``frame_end``, a short trail of the last positions, a square at the estimated position
  and the track id -- only over the frames the track spans;
* frame-by-frame tracks (``/track_points``, when present): trail, marker and id;
* ground truth (optional): small green diamonds.

``write_video`` streams a sequence window by window, draws the overlays, adds a status
strip (frame number, window, counts, legend) below the picture, optionally the panels
raw | suppressed | combined side by side, and writes an .mp4 / .avi / PNG folder
(``irdetect.io.video``). Coordinates: x = column, y = row in source pixels, the centre of
pixel (0, 0) at (0, 0); a point (x, y) is drawn at ((x + 0.5) s - 0.5, (y + 0.5) s - 0.5)
of an image scaled by s.
"""

from __future__ import annotations

import inspect
import logging
import os
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

from irdetect import tables
from irdetect.combine import window_starts
from irdetect.errors import InputError
from irdetect.exclude import exclusion_mask

log = logging.getLogger(__name__)

#: BGR colours of the overlay layers (green is kept for the truth)
COLOURS = {
    "track": (0, 140, 255),        # orange: initiated track (estimated path)
    "tracker": (0, 230, 255),      # yellow: frame-by-frame tracker
    "truth": (0, 210, 0),          # green
    "candidate": (200, 200, 200),  # light grey
    "excluded": (150, 90, 90),     # dim blue: the outline of the excluded pixels
    "text": (255, 255, 255),
}
#: BGR colours of detections, cycled by combined frame so neighbouring windows differ
WINDOW_PALETTE = ((255, 255, 0), (255, 0, 255), (255, 144, 30), (180, 105, 255))

#: fraction of pixels read to estimate display limits (every 2nd row and column)
_SAMPLE = 2
_SHIFT = 4                         # cv2 drawing: 4 fractional bits (1/16 px)
_FONT = cv2.FONT_HERSHEY_SIMPLEX


# ------------------------------------------------------------------------------------------
# contrast

def display_limits(frames, *, low: float = 0.5, high: float = 99.8) -> tuple[float, float]:
    """Robust display limits: the ``low`` and ``high`` percentiles of the pixel values.

    Parameters
    ----------
    frames : ndarray of shape (H, W) or (T, H, W)
        Any real dtype; NaN values are ignored. Every 2nd row and column is sampled.
    low, high : float
        Percentiles in [0, 100], low < high.

    Returns
    -------
    (lo, hi) : tuple of float
        hi > lo always (a flat image gets hi = lo + 1).
    """
    if not (0 <= low < high <= 100):
        raise ValueError(f"need 0 <= low < high <= 100, got low={low}, high={high}")
    arr = np.asarray(frames)
    if arr.ndim not in (2, 3) or arr.size == 0:
        raise ValueError(f"frames must have shape (H, W) or (T, H, W), got {arr.shape}")
    sample = arr[..., ::_SAMPLE, ::_SAMPLE].ravel()
    if sample.dtype.kind == "f":
        sample = sample[np.isfinite(sample)]
        if sample.size == 0:
            return 0.0, 1.0
    lo, hi = (float(v) for v in np.percentile(sample, [low, high]))
    if not hi > lo:
        hi = lo + 1.0
    return lo, hi


def stretch(frame, *, limits: tuple[float, float] | None = None, low: float = 0.5,
            high: float = 99.8, gamma: float = 1.0) -> np.ndarray:
    """Map a frame to 8-bit grey for display: u = clip((v - lo) / (hi - lo), 0, 1) ** gamma.

    Parameters
    ----------
    frame : ndarray of shape (H, W) or (T, H, W)
        uint8, uint16 or other integer types (mapped through a look-up table, so 16-bit
        data cost one table lookup per pixel) or float (NaN shows black).
    limits : (lo, hi), optional
        Display limits; default ``display_limits(frame, low=low, high=high)``.
    gamma : float
        > 0; gamma < 1 brightens the dark end (dim targets over a dark sky), > 1 darkens.

    Returns
    -------
    ndarray of uint8, the shape of ``frame``
    """
    if not (np.isfinite(gamma) and gamma > 0):
        raise ValueError(f"gamma must be a positive number, got {gamma}")
    arr = np.asarray(frame)
    lo, hi = limits if limits is not None else display_limits(arr, low=low, high=high)
    if not hi > lo:
        raise ValueError(f"limits must have hi > lo, got {limits}")
    if arr.dtype in (np.uint8, np.uint16):
        levels = np.arange(256 if arr.dtype == np.uint8 else 65536, dtype=np.float64)
        lut = _curve(levels, lo, hi, gamma)
        if arr.dtype == np.uint8:
            # as (rows, W): OpenCV 5 reads a (T, H, W) array as H x ... with W channels
            # and refuses W > 128
            flat = np.ascontiguousarray(arr).reshape(-1, arr.shape[-1]) if arr.ndim else arr
            return cv2.LUT(flat, lut).reshape(arr.shape)
        return lut[arr]
    return _curve(np.asarray(arr, np.float64), lo, hi, gamma)


def _curve(v, lo, hi, gamma):
    u = np.clip((v - lo) / (hi - lo), 0.0, 1.0)
    if gamma != 1.0:
        u = u ** gamma
    u = np.nan_to_num(u, nan=0.0)
    return np.rint(u * 255.0).astype(np.uint8)


# ------------------------------------------------------------------------------------------
# what to draw

@dataclass
class Overlay:
    """The tables of a results file, sorted for lookup by frame.

    Attributes
    ----------
    detections, candidates, tracks, track_points, truth : structured ndarray
        ``irdetect.tables`` dtypes (empty when absent). ``candidates`` holds only the
        unconfirmed ones.
    """

    detections: np.ndarray
    candidates: np.ndarray
    tracks: np.ndarray
    track_points: np.ndarray
    truth: np.ndarray
    camera: np.ndarray | None = None
    #: outlines of the excluded pixels (``irdetect.exclude``): int32 arrays (n, 1, 2) of
    #: (x, y) px, as ``cv2.findContours`` gives them
    excluded: tuple = ()
    #: the window (``combined_frame``) whose detections and candidates each frame shows
    #: (``shown_windows``), or None: every window that holds the frame
    shown: np.ndarray | None = None

    def track_at(self, row, frames) -> tuple[np.ndarray, np.ndarray]:
        """(x, y) of one TRACK row in ``frames`` (a scene track follows the camera)."""
        from irdetect.initiate import track_positions

        pos = track_positions(np.asarray(row).reshape(1), np.atleast_1d(frames),
                              self.camera)[0]
        return pos[:, 0], pos[:, 1]

    @classmethod
    def from_tables(cls, found: dict, truth: np.ndarray | None = None,
                    excluded: np.ndarray | None = None) -> "Overlay":
        """Build from a dict name -> table (e.g. ``read_results(path).tables``);
        ``excluded``: the (H, W) bool mask of the run's excluded pixels, if any."""
        def get(name):
            t = found.get(name)
            return tables.empty(name) if t is None else np.asarray(t)

        det = get("detections")
        cand = get("candidates")
        if len(cand) and "confirmed" in cand.dtype.names:
            cand = cand[~cand["confirmed"]]
        tp = get("track_points")
        tr = np.asarray(truth) if truth is not None else tables.empty("truth")
        return cls(detections=det[np.argsort(det["frame_start"], kind="stable")],
                   candidates=cand[np.argsort(cand["frame_start"], kind="stable")],
                   tracks=get("tracks"),
                   track_points=tp[np.argsort(tp["frame"], kind="stable")],
                   truth=tr[np.argsort(tr["frame"], kind="stable")],
                   camera=found.get("camera"),
                   excluded=() if excluded is None else tuple(cv2.findContours(
                       excluded.astype(np.uint8), cv2.RETR_EXTERNAL,
                       cv2.CHAIN_APPROX_SIMPLE)[0]))

    def _window_rows(self, table, t):
        if not len(table):
            return table
        span = int((table["frame_end"] - table["frame_start"]).max()) + 1
        a = np.searchsorted(table["frame_start"], t - span + 1, side="left")
        b = np.searchsorted(table["frame_start"], t, side="right")
        rows = table[a:b]
        return rows[rows["frame_end"] >= t]

    def detections_at(self, t: int) -> np.ndarray:
        """Detections whose window [frame_start, frame_end] holds frame ``t`` (of the
        window ``shown`` names for it, when set)."""
        return self._shown(self._window_rows(self.detections, t), t)

    def candidates_at(self, t: int) -> np.ndarray:
        """Unconfirmed candidates whose window holds frame ``t`` (as ``detections_at``)."""
        return self._shown(self._window_rows(self.candidates, t), t)

    def _shown(self, rows, t):
        if self.shown is None or not len(rows) or not 0 <= t < len(self.shown):
            return rows
        return rows[rows["combined_frame"] == self.shown[t]]

    def tracks_at(self, t: int) -> np.ndarray:
        """Initiated tracks with frame_start <= t <= frame_end."""
        tr = self.tracks
        return tr[(tr["frame_start"] <= t) & (tr["frame_end"] >= t)]

    def truth_at(self, t: int) -> np.ndarray:
        """Truth rows of frame ``t``."""
        a, b = np.searchsorted(self.truth["frame"], [t, t + 1])
        return self.truth[a:b]

    def track_points_between(self, a: int, b: int) -> np.ndarray:
        """Tracker rows with a <= frame <= b."""
        i, j = np.searchsorted(self.track_points["frame"], [a, b + 1])
        return self.track_points[i:j]


@dataclass(frozen=True)
class Style:
    """How overlays look.

    Attributes
    ----------
    scale : float
        Output pixels per source pixel.
    trail : int
        Frames of past positions drawn as a trail behind a track.
    candidates : bool
        Draw unconfirmed candidates.
    radius : float
        Detection circle radius in source pixels (the paper's targets are 3x3 px).
    """

    scale: float = 2.0
    trail: int = 12
    candidates: bool = False
    radius: float = 3.0

    @property
    def thickness(self) -> int:
        return max(1, int(round(self.scale * 0.75)))

    @property
    def font_scale(self) -> float:
        return 0.4 if self.scale < 2 else 0.5


def _fix(v) -> int:
    return int(round(float(v) * (1 << _SHIFT)))


def _to_px(x, y, scale):
    """Source (x, y) -> output pixel coordinates (floats)."""
    return (np.asarray(x, float) + 0.5) * scale - 0.5, (np.asarray(y, float) + 0.5) * scale - 0.5


def window_colour(combined_frame: int) -> tuple[int, int, int]:
    """BGR colour of the detections of one combined frame."""
    return WINDOW_PALETTE[int(combined_frame) % len(WINDOW_PALETTE)]


def shown_windows(n_frames: int, starts, length: int) -> np.ndarray:
    """The window each frame shows (n_frames,) int: of the windows [s, s + length) of
    ``starts`` that hold it, the one whose middle frame is nearest (the earlier on a tie);
    -1 where none does. Overlapping windows (``combine.step`` < ``length``, the tail
    window over the last frames) would otherwise draw one target's detection once per
    window, in two colours."""
    starts = np.asarray(starts, float)             # ascending (``window_starts``)
    t = np.arange(n_frames)
    if not len(starts):
        return np.full(n_frames, -1)
    first = np.searchsorted(starts, t - length + 1, "left")   # the windows holding t:
    last = np.searchsorted(starts, t, "right") - 1            # first .. last
    middle = starts + (length - 1) / 2.0
    after = np.searchsorted(middle, t, "left")                # the first middle >= t
    lo, hi = np.clip(after - 1, first, last), np.clip(after, first, last)
    pick = np.where(np.abs(t - middle[lo]) <= np.abs(t - middle[hi]), lo, hi)
    return np.where(last >= first, pick, -1)


def draw_overlay(image: np.ndarray, t: int, overlay: Overlay, style: Style = Style(), *,
                 truth: bool = True) -> dict:
    """Draw the overlays of frame ``t`` in place on a scaled BGR image.

    Parameters
    ----------
    image : ndarray of shape (round(H s), round(W s), 3) uint8
        The frame already scaled by ``style.scale``; drawn on in place.
    t : int
        Frame number.
    overlay : Overlay
    style : Style
    truth : bool
        Draw the truth rows of ``overlay`` (if any).

    Returns
    -------
    dict
        Counts drawn: ``detections``, ``candidates``, ``tracks``, ``tracker``, ``truth``.
    """
    s = style.scale
    th = style.thickness
    h, w = image.shape[:2]
    counts = {}
    for c in overlay.excluded:
        px, py = _to_px(c[:, 0, 0], c[:, 0, 1], s)
        pts = np.rint(np.column_stack([px, py]) * (1 << _SHIFT)).astype(np.int32)
        cv2.polylines(image, [pts], True, COLOURS["excluded"], 1, cv2.LINE_AA, _SHIFT)
    if style.candidates:
        cand = overlay.candidates_at(t)
        px, py = _to_px(cand["x"], cand["y"], s)
        arm = max(2.0, 1.0 * s)
        for x, y in zip(px, py):
            for dx, dy in ((arm, arm), (arm, -arm)):
                cv2.line(image, (_fix(x - dx), _fix(y - dy)), (_fix(x + dx), _fix(y + dy)),
                         COLOURS["candidate"], 1, cv2.LINE_AA, _SHIFT)
        counts["candidates"] = len(cand)
    det = overlay.detections_at(t)
    px, py = _to_px(det["x"], det["y"], s)
    r = _fix(max(style.radius * s, 5.0))
    for x, y, k in zip(px, py, det["combined_frame"]):
        cv2.circle(image, (_fix(x), _fix(y)), r, window_colour(k), th, cv2.LINE_AA, _SHIFT)
    counts["detections"] = len(det)
    tracks = overlay.tracks_at(t)
    for row in tracks:
        _draw_track(image, row, t, style, overlay)
    counts["tracks"] = len(tracks)
    counts["tracker"] = _draw_tracker(image, overlay, t, style)
    if truth and len(overlay.truth):
        rows = overlay.truth_at(t)
        px, py = _to_px(rows["x"], rows["y"], s)
        d = max(3.0, 1.5 * s)
        for x, y in zip(px, py):
            pts = np.array([[x, y - d], [x + d, y], [x, y + d], [x - d, y]])
            cv2.polylines(image, [np.rint(pts * (1 << _SHIFT)).astype(np.int32)], True,
                          COLOURS["truth"], 1, cv2.LINE_AA, _SHIFT)
        counts["truth"] = len(rows)
    return counts


def _draw_track(image, row, t, style, overlay):
    s, th = style.scale, style.thickness
    colour = COLOURS["track"]
    fs, fe = int(row["frame_start"]), int(row["frame_end"])
    if np.isfinite(row["x0"]) and np.isfinite(row["y0"]) and np.isfinite(row["vx"]):
        def at(f):
            return overlay.track_at(row, f)
        # the whole track where it is in the image at every frame of its span
        wx, wy = _to_px(*at(np.arange(fs, fe + 1)), s)
        whole = np.rint(np.column_stack([wx, wy]) * (1 << _SHIFT)).astype(np.int32)
        cv2.polylines(image, [whole], False, colour, 1, cv2.LINE_AA, _SHIFT)
        frames = np.arange(max(fs, t - style.trail), t + 1)
        tx, ty = _to_px(*at(frames), s)
        pts = np.rint(np.column_stack([tx, ty]) * (1 << _SHIFT)).astype(np.int32)
        cv2.polylines(image, [pts], False, colour, th + 1, cv2.LINE_AA, _SHIFT)
        cx, cy = tx[-1], ty[-1]
        half = max(3.0, 1.5 * s)
        cv2.rectangle(image, (_fix(cx - half), _fix(cy - half)),
                      (_fix(cx + half), _fix(cy + half)), colour, 1, cv2.LINE_AA, _SHIFT)
    else:
        # no position on the line: draw the whole line rho = x cos + y sin across the frame
        h, w = image.shape[:2]
        c, sn = np.cos(row["theta"]), np.sin(row["theta"])
        x0, y0 = row["rho"] * c, row["rho"] * sn
        big = 4.0 * (w + h)
        (ax, ay), (bx, by) = _to_px(x0 - big * sn, y0 + big * c, s), \
            _to_px(x0 + big * sn, y0 - big * c, s)
        ok, p1, p2 = cv2.clipLine((0, 0, w, h), (int(ax), int(ay)), (int(bx), int(by)))
        if not ok:
            return
        cv2.line(image, p1, p2, colour, 1, cv2.LINE_AA)
        cx, cy = (p1[0] + p2[0]) / 2, (p1[1] + p2[1]) / 2
    _label(image, f"T{int(row['track_id'])}", cx, cy, colour, style)


def _draw_tracker(image, overlay, t, style) -> int:
    if not len(overlay.track_points):
        return 0
    s, th = style.scale, style.thickness
    colour = COLOURS["tracker"]
    rows = overlay.track_points_between(t - style.trail, t)
    n = 0
    for tid in np.unique(rows["track_id"]):          # a handful of live tracks
        r = rows[rows["track_id"] == tid]
        if r["frame"][-1] != t:
            continue                                  # not alive at this frame
        px, py = _to_px(r["x"], r["y"], s)
        pts = np.rint(np.column_stack([px, py]) * (1 << _SHIFT)).astype(np.int32)
        if len(pts) > 1:
            cv2.polylines(image, [pts], False, colour, th, cv2.LINE_AA, _SHIFT)
        cv2.drawMarker(image, (int(round(px[-1])), int(round(py[-1]))), colour,
                       cv2.MARKER_TILTED_CROSS, int(max(6, 3 * s)), 1, cv2.LINE_AA)
        _label(image, str(int(tid)), px[-1], py[-1] + 2.5 * max(6, 3 * s), colour, style)
        n += 1
    return n


def _label(image, text, x, y, colour, style):
    """Text just above-right of (x, y) output px, with a dark outline, kept inside."""
    fs = style.font_scale
    (tw, tht), base = cv2.getTextSize(text, _FONT, fs, 1)
    off = max(6.0, style.radius * style.scale) + 2
    h, w = image.shape[:2]
    xi = int(np.clip(x + off, 0, max(0, w - tw - 1)))
    yi = int(np.clip(y - off, tht + 1, h - base - 1))
    put_text(image, text, (xi, yi), fs, colour)


def put_text(image, text, org, font_scale, colour=COLOURS["text"]) -> None:
    """Text with a one-pixel dark outline, readable over any background.

    The outline is the text drawn at the 8 neighbouring offsets (a thick stroke would
    change the glyph advance in OpenCV 5 and misalign the two layers).
    """
    x, y = int(org[0]), int(org[1])
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            if dx or dy:
                cv2.putText(image, text, (x + dx, y + dy), _FONT, font_scale, (0, 0, 0), 1,
                            cv2.LINE_AA)
    cv2.putText(image, text, (x, y), _FONT, font_scale, colour, 1, cv2.LINE_AA)


def scale_image(grey: np.ndarray, scale: float) -> np.ndarray:
    """Scale an 8-bit grey image (nearest neighbour up, area average down) to BGR."""
    h, w = grey.shape
    size = (max(1, int(round(w * scale))), max(1, int(round(h * scale))))
    if size != (w, h):
        grey = cv2.resize(grey, size, interpolation=cv2.INTER_NEAREST if scale >= 1
                          else cv2.INTER_AREA)
    return cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)


def status_strip(width: int, t: int, n_frames: int, counts: dict, *, window: str = "",
                 legend: list[tuple[str, tuple]] = (), font_scale: float = 0.45) -> np.ndarray:
    """A dark strip with the frame number, counts and a colour legend (two text lines).

    Returns
    -------
    ndarray of shape (h, width, 3) uint8
    """
    (_, th), base = cv2.getTextSize("Ag", _FONT, font_scale, 1)
    line = th + base + 6
    strip = np.full((2 * line + 4, width, 3), 24, np.uint8)
    parts = [f"frame {t} / {n_frames - 1}"]
    if window:
        parts.append(window)
    parts += [f"{counts[k]} {k}" for k in ("detections", "tracks", "tracker", "candidates")
              if counts.get(k)]
    cv2.putText(strip, "   ".join(parts), (6, line - base - 2), _FONT, font_scale,
                COLOURS["text"], 1, cv2.LINE_AA)
    x = 6
    y = 2 * line - base - 2
    for text, colour in legend:
        cv2.rectangle(strip, (x, y - th), (x + th, y), colour, -1)
        x += th + 4
        (tw, _), _ = cv2.getTextSize(text, _FONT, font_scale, 1)
        if x + tw > width:
            break
        cv2.putText(strip, text, (x, y), _FONT, font_scale, COLOURS["text"], 1, cv2.LINE_AA)
        x += tw + 14
    return strip


def run_exclusions(config: dict, shape) -> np.ndarray | None:
    """The (H, W) bool mask of the pixels a run excluded (its configuration's
    ``exclude``; ``irdetect.exclude``), or None: none, or a mask image no longer found
    (a warning: the picture is drawn without it)."""
    try:
        return exclusion_mask(config.get("exclude", ()), shape)
    except InputError as exc:
        log.warning("the excluded pixels are not drawn: %s", exc)
        return None


def legend_items(overlay: Overlay, style: Style, *, truth: bool,
                 detections: bool = True) -> list[tuple[str, tuple]]:
    """(label, BGR colour) of the layers that have something to draw (``detections``:
    results are drawn, their detections first)."""
    items = [("detections (colour = window)", WINDOW_PALETTE[0])] if detections else []
    if len(overlay.tracks):
        items.append(("track: estimated path, id", COLOURS["track"]))
    if len(overlay.track_points):
        items.append(("tracker", COLOURS["tracker"]))
    if style.candidates:
        items.append(("candidate", COLOURS["candidate"]))
    if truth and len(overlay.truth):
        items.append(("truth", COLOURS["truth"]))
    if overlay.excluded:
        items.append(("excluded", COLOURS["excluded"]))
    return items


# ------------------------------------------------------------------------------------------
# results <-> sequence consistency

def check_results_match(results, shape, *, sequence_name: str | None = None,
                        margin: float = 1.0) -> None:
    """Refuse results that cannot belong to a sequence of ``shape`` = (T, H, W).

    Checks the root attributes ``n_frames``, ``frame_height``, ``frame_width`` (written by
    ``irdetect process``) and the extents of the tables: every frame number below T,
    every detection / candidate / tracker position inside the frame (give or take
    ``margin`` px). A different ``input`` file name only logs a warning (files get renamed).

    Raises
    ------
    InputError
        A mismatch, naming both sizes; or a file without any image-sequence table.
    """
    path = results.path
    T, H, W = (int(v) for v in shape)
    found = results.tables
    if not any(name in found for name in ("detections", "candidates", "tracks",
                                          "track_points")):
        raise InputError("holds no /detections, /tracks or /track_points: not the results "
                         "of an image sequence", path)
    tracks = found.get("tracks")
    if tracks is not None and "scan_start" in (tracks.dtype.names or ()):
        raise InputError("holds tracks on radar scans, not on an image sequence", path)
    a = results.attrs
    want = {"n_frames": T, "frame_height": H, "frame_width": W}
    for key, value in want.items():
        if key in a and int(a[key]) != value:
            raise InputError(f"results are for a sequence of {a.get('n_frames', '?')} frames "
                             f"of {a.get('frame_width', '?')}x{a.get('frame_height', '?')} px, "
                             f"but the sequence has {T} frames of {W}x{H} px "
                             "(results of another sequence?)", path)
    if sequence_name and a.get("input") and Path(str(a["input"])).name != sequence_name:
        log.warning("%s was made from %r, not %r; drawing it anyway (sizes match)", path,
                    a["input"], sequence_name)
    for name, tcol in (("detections", "frame_end"), ("candidates", "frame_end"),
                       ("tracks", "frame_end"), ("track_points", "frame")):
        tab = found.get(name)
        if tab is None or not len(tab) or tcol not in tab.dtype.names:
            continue
        last = int(tab[tcol].max())
        if last >= T or int(tab[tcol.replace("end", "start")].min()) < 0:
            raise InputError(f"/{name} reaches frame {last}, but the sequence has {T} frames "
                             "(results of another sequence?)", path)
        if name == "tracks":
            continue
        x, y = tab["x"], tab["y"]
        ok = np.isfinite(x) & np.isfinite(y)
        if ok.any() and (x[ok].min() < -0.5 - margin or x[ok].max() > W - 0.5 + margin
                         or y[ok].min() < -0.5 - margin or y[ok].max() > H - 0.5 + margin):
            raise InputError(f"/{name} has points up to x={x[ok].max():.1f}, "
                             f"y={y[ok].max():.1f}, outside the {W}x{H} px frames "
                             "(results of another sequence?)", path)


# ------------------------------------------------------------------------------------------
# the video

def _call_with(func, params: dict, **extra):
    """Call ``func`` with the entries of ``params`` it accepts (config may hold more)."""
    names = inspect.signature(func).parameters
    return func(**extra, **{k: v for k, v in params.items() if k in names})


def _default(func, name):
    return inspect.signature(func).parameters[name].default


def _panel_title(image, text, font_scale):
    (_, th), base = cv2.getTextSize(text, _FONT, font_scale, 1)
    put_text(image, text, (4, th + 4), font_scale)


def check_gamma(gamma: float) -> None:
    """Refuse a display gamma that is not a positive number, naming ``--gamma``."""
    try:
        stretch(np.zeros((2, 2), np.uint8), limits=(0, 1), gamma=gamma)
    except ValueError as exc:
        raise InputError(f"--gamma {gamma:g}: {exc}") from None


def write_video(source, results, output, *, fps: float | None = None,
                scale: float | None = None, every: int = 1, truth=None,
                candidates: bool = False, panels: bool = False, gamma: float = 1.0,
                low: float = 0.5, high: float = 99.8, trail: int = 12,
                legend: bool = True, force: bool = False, progress: bool = False) -> dict:
    """Write the annotated video of a sequence and its results.

    Parameters
    ----------
    source : irdetect.io.FrameSource
        The sequence (frames of shape (H, W)); read one window at a time.
    results : irdetect.io.Results or None
        ``read_results`` of the results file; checked against the sequence first
        (``check_results_match``) so a mismatch fails before any frame is written. None:
        the sequence alone (with ``truth``, its annotation), the panels with the default
        configuration.
    output : str or os.PathLike
        ``.mp4``, ``.avi`` or a folder for PNG frames (``irdetect.io.video``).
    fps : float, optional
        Frames per second (default: the sequence's frame rate, else 25).
    scale : float, optional
        Output pixels per source pixel (default: the smallest integer making the picture
        at least 640 px wide, at most 4; 1 for frames that wide already).
    every : int
        Write every N-th frame (0, N, 2N, ...).
    truth : structured ndarray, optional
        ``irdetect.tables.TRUTH`` rows to draw in green.
    candidates : bool
        Also draw unconfirmed candidates.
    panels : bool
        Three panels side by side: raw | suppressed | combined frame of the window, with
        the suppressor and projection of the results' configuration.
    gamma, low, high : float
        Display stretch (``stretch``): limits are the low / high percentiles of up to
        16 frames spread over the sequence, fixed for the whole video so it does not
        flicker; the suppressed and combined panels are stretched per window.
    trail : int
        Frames of past positions behind a track.
    legend : bool
        Add the status strip (frame number, counts, legend) below the picture.
    force : bool
        Replace an existing output.
    progress : bool
        tqdm bar over the frames written.

    Returns
    -------
    dict
        ``frames`` (written), ``size`` (width, height of the output frames), ``path``.

    Raises
    ------
    InputError
        Bad output path or type, results that do not match the sequence, a bad option.
    """
    from tqdm import tqdm

    from irdetect.io.video import VideoWriter, check_video_path

    T, H, W = source.shape
    if int(every) != every or every < 1:
        raise InputError(f"--every must be an integer >= 1, got {every}")
    if scale is None:
        scale = 1.0 if W >= 640 else float(min(4, int(np.ceil(640 / W))))
    if not (np.isfinite(scale) and 0.05 <= scale <= 16):
        raise InputError(f"--scale must lie in [0.05, 16], got {scale}")
    fps = fps if fps is not None else (source.frame_rate or 25.0)
    if not (np.isfinite(fps) and fps > 0):
        raise InputError(f"--fps must be a positive number, got {fps}")
    if int(trail) != trail or trail < 0:
        raise InputError(f"--trail must be an integer >= 0, got {trail}")
    try:
        display_limits(np.zeros((2, 2)), low=low, high=high)
    except ValueError as exc:
        raise InputError(f"--percentiles {low:g} {high:g}: {exc}") from None
    check_gamma(gamma)
    inputs = (source.path,) if results is None else (results.path, source.path)
    check_video_path(output, force, inputs)
    if results is None:
        from irdetect.config import ProcessConfig

        found, config = {}, asdict(ProcessConfig())
        length, step, tail = (config["combine"][k] for k in ("length", "step", "tail"))
    else:
        check_results_match(results, source.shape, sequence_name=Path(source.path).name)
        found, config = results.tables, results.config
        length, step, tail = results.windows()
    overlay = Overlay.from_tables(found, truth, run_exclusions(config, (H, W)))
    style = Style(scale=float(scale), trail=int(trail), candidates=candidates)
    starts = window_starts(T, length=length, step=step, tail=tail)
    overlay.shown = shown_windows(T, starts, length)
    sup_params = dict(config.get("suppress", {}))
    comb_params = {k: v for k, v in config.get("combine", {}).items()
                   if k not in ("length", "step")}
    history = int(sup_params.get("history", 0)) if sup_params.get("method") == "temporal" else 0
    # display limits of the raw frames: a sample of frames spread over the sequence
    pick = np.unique(np.linspace(0, T - 1, min(T, 16)).round().astype(int))
    limits = display_limits(np.stack([source[int(i)] for i in pick]), low=low, high=high)
    items = legend_items(overlay, style, truth=truth is not None,
                         detections=results is not None) if legend else []
    wanted = range(0, T, int(every))
    bar = tqdm(total=len(wanted), unit="frame", desc="video", disable=not progress,
               leave=False)
    written, size = 0, None
    tail = None
    with VideoWriter(output, fps=fps, force=force, inputs=inputs) as out:
        for start, block in source.windows(length):
            views = [stretch(block, limits=limits, gamma=gamma)]
            titles = ["raw"]
            if panels:
                from irdetect.combine import combine
                from irdetect.suppress import suppress

                residual = _call_with(suppress, sup_params, frames=block,
                                      previous=tail if history else None)
                comb = _call_with(combine, comb_params, frames=residual, length=len(block),
                                  step=len(block))[0]
                views.append(stretch(residual, low=low, high=high, gamma=gamma))
                views.append(np.broadcast_to(stretch(comb, low=low, high=high, gamma=gamma),
                                             block.shape))
                k = start // length
                titles += [f"suppressed ({sup_params.get('method', 'tophat')})",
                           f"combined frame {k} "
                           f"({comb_params.get('projection', _default(combine, 'projection'))})"]
                if history:
                    tail = block[-history:] if tail is None else \
                        np.concatenate([tail, block])[-history:]
            for i in range(len(block)):
                t = start + i
                if t % every:
                    continue
                pictures = []
                for v, title in zip(views, titles):
                    img = scale_image(np.ascontiguousarray(v[i]), style.scale)
                    counts = draw_overlay(img, t, overlay, style, truth=truth is not None)
                    if panels:
                        _panel_title(img, title, style.font_scale)
                    pictures.append(img)
                if panels:
                    gap = np.full((pictures[0].shape[0], 4, 3), 64, np.uint8)
                    picture = np.hstack([pictures[0], gap, pictures[1], gap, pictures[2]])
                else:
                    picture = pictures[0]
                if legend:
                    k = int(overlay.shown[t])
                    if results is None:
                        window = "no results"
                    else:
                        # the detection swatch takes the colour of this window
                        items[0] = (items[0][0], window_colour(max(k, 0)))
                        window = (f"window {k}: frames {starts[k]}-{starts[k] + length - 1}"
                                  if k >= 0 else "in no window")
                    picture = np.vstack([picture, status_strip(
                        picture.shape[1], t, T, counts, window=window, legend=items,
                        font_scale=max(0.4, style.font_scale))])
                out.write(picture, index=t)
                size = (picture.shape[1], picture.shape[0])
                written += 1
                bar.update(1)
    bar.close()
    log.info("wrote %s: %d frames of %dx%d px", output, written, *size)
    return {"frames": written, "size": size, "path": os.fspath(output)}
