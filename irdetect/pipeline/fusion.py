"""The fusion of the two paths: one detection per target per window, each saying which
path found it, and the track initiation on them.

The combined-frame path (``irdetect.pipeline.combined``) integrates 12 frames and sees
targets too dim for any single frame; the per-frame path (``irdetect.pipeline.perframe``)
follows targets too fast for a combined frame. Per window (``fuse_paths``):

* every combined-frame detection that reaches its window's operating point
  (``irdetect.operating``: ``significance`` >= ``level``) is kept, with its track's local
  SNR per frame (``snr``: the matched, standardised residual along the track over the
  window) and the share of the window's frames with a per-frame peak on it (``support``),
  so both paths' rows carry the same score;
* every kept per-frame track gives a detection at the window's middle frame;
* a combined-frame and a per-frame detection within ``MERGE_PX`` of each other are one
  target (``path`` both bits; the per-frame position, measured frame by frame, is kept);
  the other combined-frame detections within ``MERGE_PX`` of a per-frame track's path over
  the window are pieces of that target's streak and are dropped (``streak_distance``).

Then Hough + subtractive clustering initiates the tracks on the fused detections
(``initiate_tracks``, the papers' hand-off; a second pass asks a line that leaves the
frame for the votes of the windows it is inside in, and every track's span is cut to the
frame), each track's ``path`` the union of its detections'. Coordinates: x = column,
y = row, px; time in frames.
"""

from __future__ import annotations

from dataclasses import asdict

import cv2
import numpy as np
from scipy import sparse
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from irdetect import tables
from irdetect.binning import to_binned, to_input
from irdetect.config import ProcessConfig
from irdetect.initiate.base import vote_threshold

_NEIGHBOURS = np.ones((3, 3), np.uint8)

#: a detection of one path and one of the other this close (px) in a window are one target
#: (two position errors of the per-frame path's 3-sigma gate apart at sigma 1 px)
MERGE_PX = 6.0


def dilated_sum(matched: np.ndarray) -> np.ndarray:
    """The sum over a window's matched frames (L, H, W) of each frame dilated by 3 x 3
    (the largest value of the 3 x 3 pixels about each pixel: what ``track_mean`` reads
    along a track at rest). float32 (H, W)."""
    out = np.zeros(matched.shape[1:], np.float32)
    for f in matched:                    # a loop over the window's frames
        out += cv2.dilate(f, _NEIGHBOURS)
    return out


def registered_mean(blocks, ref) -> np.ndarray:
    """The mean of matched frames, each dilated by 3 x 3 (as ``dilated_sum``) and moved by
    the camera's whole-pixel motion into the image of a reference frame: structure at
    rest in the scene adds up where it lies in that frame, as it does along a chain in
    scene coordinates.

    Parameters
    ----------
    blocks : sequence of (ndarray of shape (L_j, H, W), ndarray of shape (L_j, 2))
        Matched standardised frames and the camera's offsets (x, y px) of each.
    ref : array_like of shape (2,)
        The reference frame's offset: a scene point at p + C_t in frame t is at
        p + ``ref`` there, so frame t moves by round(ref - C_t).

    Returns
    -------
    ndarray of float32 of shape (H, W)
        The mean over the frames that cover each pixel (0 where none does).
    """
    first = blocks[0][0]
    h, w = first.shape[1:]
    total = np.zeros((h, w), np.float32)
    count = np.zeros((h, w), np.float32)
    for matched, offsets in blocks:      # a loop over a few windows
        for f, c in zip(matched, offsets):   # ... and their frames
            dx, dy = (int(v) for v in np.round(np.asarray(ref, float) - c))
            if abs(dx) >= w or abs(dy) >= h:
                continue
            d = cv2.dilate(f, _NEIGHBOURS)
            src = d[max(0, -dy):h - max(0, dy), max(0, -dx):w - max(0, dx)]
            ys, xs = slice(max(0, dy), h - max(0, -dy)), slice(max(0, dx), w - max(0, -dx))
            total[ys, xs] += src
            count[ys, xs] += 1.0
    return np.divide(total, count, out=np.zeros_like(total), where=count > 0)


def _track_xy(det: np.ndarray, times: np.ndarray, mid: float):
    """Positions (x, y px) of detections' straight tracks at frames ``times`` (N, F)."""
    t = np.asarray(times, np.float64) - mid
    vx, vy = np.nan_to_num(det["vx"]), np.nan_to_num(det["vy"])
    return det["x"][:, None] + vx[:, None] * t[None], det["y"][:, None] + vy[:, None] * t[None]


def track_values(det: np.ndarray, start: int, matched: np.ndarray, mid: float,
                 reach: int = 1) -> np.ndarray:
    """The largest matched value in the (2 reach + 1) square pixels about each
    detection's track position in each frame of one window (3 x 3 by default: a track
    1 px off the target's peak, the combined frame's position error, still reads its
    SNR).

    Parameters
    ----------
    det : structured ndarray
        ``tables.DETECTION`` rows: position (x, y px) at frame ``mid``, image velocity
        (vx, vy px/frame; NaN taken as 0).
    start : int
        The window's first frame.
    matched : ndarray of shape (L, H, W)
        The window's matched standardised frames.
    mid : float
        The frame the positions are at.
    reach : int
        Half side of the square read about each position (px).

    Returns
    -------
    ndarray of shape (N, L), float32
    """
    L, h, w = matched.shape
    x, y = _track_xy(det, start + np.arange(L), mid)                      # (N, L)
    side = np.arange(-reach, reach + 1)
    # the square's rows and columns, clipped to the frame: (N, L, S) each
    rows = np.clip(np.rint(y).astype(np.intp)[..., None] + side, 0, h - 1)
    cols = np.clip(np.rint(x).astype(np.intp)[..., None] + side, 0, w - 1)
    square = matched[np.arange(L)[None, :, None, None], rows[..., :, None],
                     cols[..., None, :]]                                   # (N, L, S, S)
    return square.max(axis=(2, 3)).astype(np.float32, copy=False)


def track_mean(det: np.ndarray, blocks, mid: float) -> np.ndarray:
    """Mean of ``track_values`` (3 x 3) over the frames of several windows.

    Parameters
    ----------
    det : structured ndarray
        ``tables.DETECTION`` rows (see ``track_values``).
    blocks : sequence of (int, ndarray of shape (L_j, H, W))
        (first frame, matched standardised frames) of the windows to read.
    mid : float
        The frame the positions are at.

    Returns
    -------
    ndarray of shape (N,)
    """
    total, count = np.zeros(len(det)), 0
    for start, matched in blocks:        # a loop over a few windows
        total += track_values(det, start, matched, mid).sum(axis=1, dtype=np.float64)
        count += len(matched)
    return total / max(count, 1)


def along_track(det: np.ndarray, matched, start: int, peaks, radius: float):
    """Local SNR per frame and per-frame support of detections along their tracks.

    Parameters
    ----------
    det : structured ndarray
        ``tables.DETECTION`` rows of one window: position (x, y px) at the window's
        middle frame, image velocity (vx, vy px/frame; NaN taken as 0).
    matched : ndarray of shape (L, H, W)
        The window's matched, standardised frames (frames start .. start + L - 1).
    start : int
        The window's first frame.
    peaks : structured ndarray or None
        ``tables.FRAME_DETECTION`` rows of the window (None: support NaN).
    radius : float
        A peak within ``radius`` px of the track's position in its frame supports it.

    Returns
    -------
    snr, support : ndarray of shape (N,)
        ``track_mean`` over the window's L frames, and the share of the L frames with a
        peak within ``radius``.
    """
    n, L = len(det), len(matched)
    if not n:
        return np.zeros(0), np.zeros(0)
    mid = start + (L - 1) / 2.0
    snr = track_mean(det, [(start, matched)], mid)
    if peaks is None:
        return snr, np.full(n, np.nan)
    x, y = _track_xy(det, start + np.arange(L), mid)
    hit = np.zeros((n, L), bool)
    for i in range(L):                   # a loop over the window's frames
        p = peaks[peaks["frame"] == start + i]
        if len(p):
            d, _ = cKDTree(np.column_stack([p["x"], p["y"]])).query(
                np.column_stack([x[:, i], y[:, i]]), distance_upper_bound=radius)
            hit[:, i] = np.isfinite(d)
    return snr, hit.mean(axis=1)


#: a per-frame peak within this many position sigmas of a combined-frame detection's track
#: supports it (the per-frame path's gate)
SUPPORT_GATE = 3.0


def streak_distance(points: np.ndarray, tracks: np.ndarray) -> np.ndarray:
    """Distance (px) of each point to each straight track's path over its frames.

    Parameters
    ----------
    points : structured ndarray
        Rows with x, y (px; x = column, y = row).
    tracks : structured ndarray
        ``tables.DETECTION`` rows: position (x, y) at the middle of frame_start ..
        frame_end, velocity (vx, vy px/frame; NaN taken as 0).

    Returns
    -------
    ndarray of shape (len(points), len(tracks))
        The distance to the segment from the track's position at frame_start to the one
        at frame_end.
    """
    half = 0.5 * (tracks["frame_end"] - tracks["frame_start"]).astype(float)
    ux, uy = np.nan_to_num(tracks["vx"]) * half, np.nan_to_num(tracks["vy"]) * half
    px = points["x"][:, None] - tracks["x"][None]                       # (P, T)
    py = points["y"][:, None] - tracks["y"][None]
    s = np.clip((px * ux + py * uy) / np.maximum(ux * ux + uy * uy, 1e-12), -1.0, 1.0)
    return np.hypot(px - s * ux, py - s * uy)


def fuse_paths(combined: np.ndarray, frame_tracks: np.ndarray) -> np.ndarray:
    """One detection per target per window from both paths (module notes).

    Parameters
    ----------
    combined : structured ndarray
        The combined-frame path's ``tables.DETECTION`` rows.
    frame_tracks : structured ndarray
        ``tables.FRAME_TRACK`` rows; those ``kept`` become detections.

    Returns
    -------
    structured ndarray
        ``tables.DETECTION`` rows in window order, ``path`` the paths that found each.
    """
    comb = combined.copy()
    ft = frame_tracks[frame_tracks["kept"]]
    frame = tables.from_columns(
        tables.DETECTION, x=ft["x"], y=ft["y"], frame_start=ft["frame_start"],
        frame_end=ft["frame_end"], combined_frame=ft["combined_frame"], intensity=ft["score"],
        score=ft["score"], vx=ft["vx"], vy=ft["vy"], n_members=ft["n_points"],
        path=np.full(len(ft), tables.PATH_FRAME, np.int8), snr=ft["score"],
        significance=ft["score"], level=np.full(len(ft), -np.inf),
        support=ft["n_points"] / np.maximum(1, ft["frame_end"] - ft["frame_start"] + 1))
    # a combined detection near a per-frame one of its window is that target: one row
    # (pairs one to one, nearest first, so two targets side by side stay two)
    same = np.zeros(len(comb), bool)
    for k in np.unique(frame["combined_frame"]):        # a loop over windows
        ci = np.flatnonzero(comb["combined_frame"] == k)
        fi = np.flatnonzero(frame["combined_frame"] == k)
        if not len(ci):
            continue
        d = np.hypot(frame["x"][fi, None] - comb["x"][None, ci],
                     frame["y"][fi, None] - comb["y"][None, ci])
        rows, cols = linear_sum_assignment(np.where(d <= MERGE_PX, d, 1e9))
        ok = d[rows, cols] <= MERGE_PX
        f, c = fi[rows[ok]], ci[cols[ok]]
        frame["path"][f] |= tables.PATH_COMBINED
        frame["snr"][f] = np.fmax(frame["snr"][f], comb["snr"][c])
        frame["significance"][f] = np.fmax(frame["significance"][f], comb["significance"][c])
        same[c] = True
        # the rest that lie on a per-frame track's path over the window are pieces of that
        # target's streak in the combined frame (12 frames x its speed long)
        near = streak_distance(comb[ci], frame[fi]).min(axis=1, initial=np.inf)
        same[ci] |= near <= MERGE_PX
    out = np.concatenate([comb[~same], frame])
    return out[np.argsort(out["combined_frame"], kind="stable")]


def track_paths(tracks: np.ndarray, detections: np.ndarray, camera, gate: float) -> np.ndarray:
    """The union of the ``path`` bits of the detections each track holds (those of its
    span within ``gate`` px of its positions); int8 of shape (n_tracks,)."""
    out = np.zeros(len(tracks), np.int8)
    if not len(tracks) or not len(detections):
        return out
    rows, cols, _ = _support(tracks, detections, camera, gate)
    bits = detections["path"][cols] & (tables.PATH_COMBINED | tables.PATH_FRAME)
    np.bitwise_or.at(out, rows, bits.astype(np.int8))
    return out


def initiate_tracks(detections: np.ndarray, config: ProcessConfig,
                    camera=None, *, shape: tuple[int, int] | None = None,
                    starts=None, length: int | None = None) -> np.ndarray:
    """Tracks from the confirmed detections (``irdetect.initiate``), TRACK table.

    With the camera's offsets (a CAMERA table) of a moving camera, tracks are initiated
    twice: on the image positions (a target the camera holds, whose scene path is the
    camera's) and on the scene positions, image minus offset (a target straight in the
    scene under a panning or shaking camera; ``scene`` rows, their positions follow the
    camera, ``irdetect.initiate.track_positions``). Tracks that hold a target another
    track holds better are dropped (``_distinct_tracks``).

    Given the frame's ``shape`` and the windows (``starts``, ``length``), a line that
    leaves the frame needs its votes only from the windows it is inside in
    (``_leaving_tracks``): Zhang et al.'s threshold, ``vote_fraction`` of the scans, is
    that of a radar whose target stays in view, and a target that crosses the frame in 4
    windows of 11 could never reach 0.6 x 10 votes.
    """
    ic = config.initiate
    params = asdict(ic)
    tracks = _both_frames(detections, camera, params)
    scans = len(np.unique(detections["combined_frame"]))
    need = max(2, vote_threshold(ic.vote_fraction, min(scans, ic.window or scans)))
    gate = float(ic.gate * ic.sigma)
    out = tracks[_distinct_tracks(tracks, detections, camera, gate, need)]
    out = out[_lines_of_their_own(out, detections, camera, gate)]
    if shape is not None and starts is not None and len(starts) >= LEAVING_VOTES:
        extra, votes = _leaving_tracks(detections, camera, params, out, shape=shape,
                                       starts=np.asarray(starts), length=int(length))
        if len(extra):
            both = np.concatenate([out, extra])
            needs = np.concatenate([np.full(len(out), need), votes])
            out = both[_distinct_tracks(both, detections, camera, gate, needs)]
        out = _inside_frame(out, camera, shape)
    out["track_id"] = np.arange(len(out))
    return out


def _lines_of_their_own(tracks, detections, camera, gate: float) -> np.ndarray:
    """Mask of the tracks that are more than a line through two detections.

    Any two detections of different windows lie on a line, so a track that fewer than
    ``LEAVING_VOTES`` detections voted for or support (a sequence of 3 windows asks for
    2 votes) has no evidence of its own in their positions. Each detection carries its
    own image velocity, measured over its window (its per-frame track's or its chain's);
    such a track is kept only when that velocity agrees with the line's at the
    detection: moved on with its own velocity to either end of its window, the detection
    stays within ``gate`` px of where the line moves it, |v - v_line| (frame_end -
    frame_start) / 2 <= ``gate``. A line's image velocity is its own, plus the camera's
    over the window for a ``scene`` track. A detection without a velocity (NaN) does not
    judge."""
    from irdetect.initiate import camera_at

    keep = np.ones(len(tracks), bool)
    if not len(tracks):
        return keep
    rows, cols, _ = _support(tracks, detections, camera, gate)
    bounds = np.searchsorted(rows, np.arange(len(tracks) + 1))
    few = (np.diff(bounds) < LEAVING_VOTES) | (tracks["n_points"] < LEAVING_VOTES)
    for i in np.flatnonzero(few):               # a loop over a few tracks
        det = detections[cols[bounds[i]:bounds[i + 1]]]
        v = np.tile([tracks["vx"][i], tracks["vy"][i]], (len(det), 1))
        span = (det["frame_end"] - det["frame_start"]).astype(float)
        if tracks["scene"][i] and camera is not None:
            ends = camera_at(camera, np.concatenate([det["frame_start"], det["frame_end"]]))
            v += (ends[len(det):] - ends[:len(det)]) / np.maximum(span, 1.0)[:, None]
        miss = np.hypot(det["vx"] - v[:, 0], det["vy"] - v[:, 1]) * 0.5 * span
        keep[i] = not (miss > gate).any()          # NaN velocities compare False
    return keep


def _inside_frame(tracks, camera, shape) -> np.ndarray:
    """``tracks`` with each span cut to the frames its line is inside the frame in (a
    track's span is its windows'; a target that leaves mid-window is not where the line
    goes on to), ``x0``, ``y0`` (and a scene track's ``rho``) moved to the new first
    frame. A track whose line is inside in no frame of its span keeps it."""
    from irdetect.initiate import camera_at, track_positions

    out = tracks.copy()
    h, w = shape
    for i, tr in enumerate(tracks):                    # a loop over the tracks (a handful)
        f = np.arange(tr["frame_start"], tr["frame_end"] + 1)
        pos = track_positions(tracks[i:i + 1], f, camera)[0]
        ok = np.flatnonzero((pos[:, 0] >= 0) & (pos[:, 0] <= w - 1)
                            & (pos[:, 1] >= 0) & (pos[:, 1] <= h - 1))
        if not len(ok) or (ok[0] == 0 and ok[-1] == len(f) - 1):
            continue
        out["frame_start"][i], out["frame_end"][i] = f[ok[0]], f[ok[-1]]
        out["x0"][i], out["y0"][i] = pos[ok[0]]
        if tr["scene"]:
            # rho is in the image coordinates of the first frame (``_scene_tracks``)
            move = np.diff(camera_at(camera, [tr["frame_start"], f[ok[0]]]), axis=0)[0]
            out["rho"][i] += move[0] * np.cos(tr["theta"]) + move[1] * np.sin(tr["theta"])
    return out


def _both_frames(detections, camera, params: dict) -> np.ndarray:
    """Tracks initiated on the image positions and, for a moving camera, on the scene
    positions too (``_scene_tracks``)."""
    from irdetect.initiate import initiate_detections

    tracks = initiate_detections(detections, **params)
    if camera is not None and len(camera) >= 2 and len(detections) >= 2 and (
            np.ptp(camera["dx"]) >= MOVING_PX or np.ptp(camera["dy"]) >= MOVING_PX):
        tracks = np.concatenate([tracks, _scene_tracks(detections, camera, params)])
    return tracks


#: the fewest detections a track of a line that leaves the frame needs (a line through 2
#: points is no evidence)
LEAVING_VOTES = 3


def _leaving_tracks(detections, camera, params: dict, tracks, *, shape, starts,
                    length: int) -> tuple[np.ndarray, np.ndarray]:
    """Tracks of lines that are inside the frame in fewer windows than the initiation's
    (fast targets crossing it, and targets that enter or leave), on the detections no
    track of ``tracks`` holds.

    The candidates come from a Hough of those detections at ``LEAVING_VOTES`` votes; one
    is kept when its detections reach ``vote_fraction`` of the windows whose middle
    frame its line is inside the frame in (at most ``window`` of them), and at least
    ``LEAVING_VOTES``, and when that count is below the windows of the sequence (a line
    inside throughout had its vote in the first pass).

    Parameters
    ----------
    detections : structured ndarray
        ``tables.DETECTION`` rows.
    camera : structured ndarray or None
        ``tables.CAMERA`` rows.
    params : dict
        ``InitiateConfig`` as keywords.
    tracks : structured ndarray
        The tracks found so far (``tables.TRACK``).
    shape : (int, int)
        Frame (H, W).
    starts : ndarray of int
        First frame of every window of the sequence; ``length`` frames per window.

    Returns
    -------
    tracks : structured ndarray
        The ``tables.TRACK`` rows kept.
    votes : ndarray of int
        The detections each needs.
    """
    from irdetect.initiate import track_positions

    gate = float(params["gate"] * params["sigma"])
    free = np.ones(len(detections), bool)
    free[_support(tracks, detections, camera, gate)[1]] = False
    rest = detections[free]
    scans = len(np.unique(rest["combined_frame"]))
    if scans < LEAVING_VOTES:
        return tables.empty(tables.TRACK), np.zeros(0, np.int64)
    window = int(params["window"]) or len(starts)
    # the fraction of a Hough window's scans that is LEAVING_VOTES votes
    low = LEAVING_VOTES / min(window, scans)
    cand = _both_frames(rest, camera, {**params, "vote_fraction": low, "min_hits": low})
    if not len(cand):
        return cand, np.zeros(0, np.int64)
    h, w = shape
    mid = starts + 0.5 * (length - 1)
    seen = np.zeros(len(cand), np.int64)
    for i in range(0, len(cand), 64):    # (64, windows) positions at a time: a long
        pos = track_positions(cand[i:i + 64], mid, camera)    # sequence has many of both
        seen[i:i + 64] = ((pos[..., 0] >= 0) & (pos[..., 0] <= w - 1)
                          & (pos[..., 1] >= 0) & (pos[..., 1] <= h - 1)).sum(axis=1)
    need = np.maximum(LEAVING_VOTES, [vote_threshold(params["vote_fraction"], int(n))
                                      for n in np.minimum(seen, window)])
    keep = (cand["n_points"] >= need) & (seen < len(starts))
    return cand[keep], need[keep]


def _scene_tracks(detections: np.ndarray, camera, params: dict) -> np.ndarray:
    """Tracks initiated on the detections' scene positions (image minus the camera's
    offset at their time), ``scene`` rows in the image coordinates of their first frame."""
    from irdetect.initiate import camera_at, initiate_detections

    t = 0.5 * (detections["frame_start"] + detections["frame_end"])
    scene_det = detections.copy()
    off = camera_at(camera, t)
    scene_det["x"] -= off[:, 0]
    scene_det["y"] -= off[:, 1]
    scene = initiate_detections(scene_det, **params)
    if len(scene):
        start = camera_at(camera, scene["frame_start"])
        scene["x0"] += start[:, 0]
        scene["y0"] += start[:, 1]
        scene["rho"] += (start[:, 0] * np.cos(scene["theta"])
                         + start[:, 1] * np.sin(scene["theta"]))
        scene["scene"] = True
    return scene


#: the camera's offsets over the sequence spanning this many px make it "moving" for the
#: track initiation (scene tracks are tried beside the image ones)
MOVING_PX = 1.0


def _support(tracks, detections, camera, gate: float):
    """The detections each track holds: those whose time lies in the track's span and
    that are within ``gate`` px of the track's position then.

    Returns
    -------
    rows, cols : ndarray of int
        Track and detection indices of each (track, detection) pair held, sorted by track,
        then by detection.
    dist : ndarray of float
        Each pair's distance, px.

    Only the detections in a track's span are measured, so the work and memory grow with
    the detections of the tracks' spans, not with tracks x detections (a long sequence
    has many of both).
    """
    from irdetect.initiate import positions_at

    t = 0.5 * (detections["frame_start"] + detections["frame_end"])
    order = np.argsort(t, kind="stable")
    lo = np.searchsorted(t[order], tracks["frame_start"], "left")
    n = np.maximum(np.searchsorted(t[order], tracks["frame_end"], "right") - lo, 0)
    rows = np.repeat(np.arange(len(tracks)), n)
    cols = order[np.arange(n.sum()) + np.repeat(lo - (np.cumsum(n) - n), n)]
    by_index = np.lexsort((cols, rows))
    rows, cols = rows[by_index], cols[by_index]
    pos = positions_at(tracks[rows], t[cols], camera)
    dist = np.hypot(pos[:, 0] - detections["x"][cols], pos[:, 1] - detections["y"][cols])
    held = dist <= gate
    return rows[held], cols[held], dist[held]


def _distinct_tracks(tracks, detections, camera, gate: float, need) -> np.ndarray:
    """Indices of tracks to keep, best first (more support, then the smaller mean
    distance): a track is dropped when half its support or more is a better kept track's
    (one target claimed twice), or when fewer than ``need`` of its detections are no kept
    track's (not a line of its own: a piece of a target that turns, or clutter that
    borrows a target's detections; two targets that cross share the crossing and keep
    the rest).

    A track's support is the detections of its span within ``gate`` px of its positions;
    ``need`` the detections a Hough cell needs (the vote threshold; one per track, or
    one for all)."""
    if len(tracks) < 2:
        return np.arange(len(tracks))
    rows, cols, dist = _support(tracks, detections, camera, gate)
    n = len(tracks)
    count = np.bincount(rows, minlength=n)
    mean = np.where(count > 0, np.bincount(rows, dist, minlength=n) / np.maximum(count, 1),
                    np.inf)
    order = np.lexsort((mean, -count))
    need = np.broadcast_to(np.asarray(need), (n,))
    bounds = np.searchsorted(rows, np.arange(n + 1))
    held = sparse.csr_matrix((np.ones(len(rows), np.int64), (rows, cols)),
                             shape=(n, len(detections)))
    shared = (held @ held.T).tocsr()    # (tracks, tracks): the detections two tracks share
    kept = np.zeros(n, bool)
    claimed = np.zeros(len(detections), bool)
    for i in order:                     # a loop over the tracks
        mine = cols[bounds[i]:bounds[i + 1]]
        row = slice(shared.indptr[i], shared.indptr[i + 1])
        others, both = shared.indices[row], shared.data[row]
        of_kept = kept[others]
        claimed_twice = (both[of_kept] >= 0.5 * np.minimum(count[i], count[others[of_kept]]))
        if kept.any() and (count[i] == 0 or (~claimed[mine]).sum() < need[i]
                           or claimed_twice.any()):
            continue
        kept[i] = True
        claimed[mine] = True
    return np.flatnonzero(kept)


def finish(combined: np.ndarray, peaks: np.ndarray, camera: np.ndarray,
           config: ProcessConfig, *, n_frames: int, shape: tuple[int, int]) -> dict:
    """The run's final tables from what the windows gave: the per-frame path's tracks, the
    fused detections and the tracks initiated on them.

    Parameters
    ----------
    combined : structured ndarray
        The combined-frame path's ``tables.DETECTION`` rows of every window.
    peaks : structured ndarray
        The per-frame path's ``tables.FRAME_DETECTION`` rows of every frame.
    camera : structured ndarray
        ``tables.CAMERA`` rows, one per frame.
    config : ProcessConfig
        The configuration the run used (``fit_config``'s, for short sequences).
    n_frames : int
    shape : (int, int)
        Frame (H, W) as read (before ``suppress.bin``: the tables are in its pixels, and
        so are those returned).

    Returns
    -------
    dict
        ``frame_tracks`` (``tables.FRAME_TRACK``), ``detections`` (``tables.DETECTION``,
        those inside the image at their window's middle frame) and ``tracks``
        (``tables.TRACK``, ``path`` set; every detection votes, outside or not).
    """
    from irdetect.combine import window_starts
    from irdetect.peaks import frame_level
    from irdetect.pipeline.perframe import frame_tracks

    fc, cc = config.frame, config.combine
    # a binned run's tables come in the input's pixels; its stages work in binned ones
    b = config.suppress.bin
    combined = to_binned("combined_detections", combined, b)
    peaks, camera = to_binned("frame_detections", peaks, b), to_binned("camera", camera, b)
    shape = (shape[0] // b, shape[1] // b)
    starts = window_starts(n_frames, length=cc.length, step=cc.step, tail=cc.tail)
    if fc.enabled:
        level = frame_level(shape, fc.false_rate)
        ft = frame_tracks(peaks, camera, starts, cc.length, shape=shape, n_frames=n_frames,
                          level=level, false_rate=fc.false_rate, sigma=fc.sigma,
                          max_speed=fc.max_speed, false_tracks=fc.false_tracks,
                          confirm_m=fc.confirm_m, confirm_n=fc.confirm_n,
                          clutter_speed=fc.clutter_speed)
    else:
        ft = tables.empty(tables.FRAME_TRACK)
    # the combined-frame path's operating point (``irdetect.operating``; -inf: none)
    combined = combined[~(combined["significance"] < combined["level"])]
    detections = fuse_paths(combined, ft) if fc.enabled else combined
    # the Hough's scans are the windows every ``step`` frames: the tail window, which
    # overlaps the last of them, would be one more scan to vote in (raising the votes a
    # line needs) and a second vote for what that one saw; it extends the tracks
    regular = len(window_starts(n_frames, length=cc.length, step=cc.step))
    tail = detections["combined_frame"] >= regular
    gate = config.initiate.gate * config.initiate.sigma
    tracks = initiate_tracks(detections[~tail], config, camera, shape=shape,
                             starts=starts[:regular], length=cc.length)
    tracks = extend_tracks(tracks, detections[tail], camera, gate)
    tracks["path"] = track_paths(tracks, detections, camera, gate)
    # a detection whose position at its window's middle frame lies outside the image
    # was seen in under half of the window's frames (the target entered after that frame
    # or left before it): it votes for its track's line, but is not reported as seen
    h, w = shape
    inside = ((detections["x"] >= -0.5) & (detections["x"] <= w - 0.5)
              & (detections["y"] >= -0.5) & (detections["y"] <= h - 0.5))
    return {"frame_tracks": to_input("frame_tracks", ft, b),
            "detections": to_input("detections", detections[inside], b),
            "tracks": to_input("tracks", tracks, b)}


def extend_tracks(tracks: np.ndarray, detections: np.ndarray, camera, gate: float) -> np.ndarray:
    """``tracks`` with each one that a detection of the tail window lies on (within
    ``gate`` px of its position at the detection's time, in its span) extended to that
    window's last frame, and that detection counted in ``n_points``.

    Parameters
    ----------
    tracks : structured ndarray
        ``tables.TRACK`` rows.
    detections : structured ndarray
        ``tables.DETECTION`` rows of the tail window (``CombineConfig.tail``).
    camera : structured ndarray or None
        ``tables.CAMERA`` rows (a ``scene`` track's positions follow the camera).
    gate : float
        px.
    """
    out = tracks.copy()
    if not (len(out) and len(detections)):
        return out
    rows, cols, _ = _support(out, detections, camera, gate)
    np.maximum.at(out["frame_end"], rows, detections["frame_end"][cols])
    out["n_points"][np.unique(rows)] += 1
    return out
