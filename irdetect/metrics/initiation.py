"""Track-initiation scores: Pt per target, Pc, and OSPA / GOSPA of track positions.

Matching rule (shared/design/algorithms.md section 2): a track initiates a target when
its line rho = x cos(theta) + y sin(theta) passes within ``k`` sigma (default 3) of every
true position of that target in the window; tracks and targets are assigned one-to-one
(Hungarian on the largest normalised distance). Pt (Zhang et al. ref. [10]) is the share
of (run, window) pairs in which a target is initiated; Pc = false tracks / all tracks.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import linear_sum_assignment


def match_lines(rho, theta, targets, *, sigma, k: float = 3.0, scene=None,
                scene_targets=None):
    """One-to-one assignment of track lines to targets.

    Parameters
    ----------
    rho, theta : array_like of shape (K,)
        Track lines (theta in [0, pi)).
    targets : list of ndarray of shape (n_j, 2)
        True positions (x, y) of each target in the window.
    sigma : float or list of ndarray of shape (n_j,)
        Measurement sigma (per target position when a list).
    k : float
        Gate in sigmas.
    scene : array_like of bool of shape (K,), optional
        Tracks whose lines are in scene coordinates: they are measured against
        ``scene_targets`` (the same positions, in the same order, minus the camera's
        offset of their frames) instead of ``targets``.
    scene_targets : list of ndarray of shape (n_j, 2), optional
        With ``scene``.

    Returns
    -------
    ndarray of shape (J,) of int
        Track index matched to each target, -1 when none.
    """
    rho = np.asarray(rho, float)
    theta = np.asarray(theta, float)
    J, K = len(targets), rho.size
    out = np.full(J, -1, np.int64)
    if J == 0 or K == 0:
        return out
    scene = np.zeros(K, bool) if scene is None else np.asarray(scene, bool)

    def largest(xy, s, cols):
        """The largest distance (in sigmas) of the positions xy from each line of cols."""
        xy = np.asarray(xy, float).reshape(-1, 2)
        d = np.abs(np.outer(xy[:, 0], np.cos(theta[cols]))
                   + np.outer(xy[:, 1], np.sin(theta[cols])) - rho[None, cols])
        return (d / np.broadcast_to(s, (len(xy),))[:, None]).max(axis=0)

    cost = np.full((J, K), np.inf)
    for j, pos in enumerate(targets):                     # a handful of targets
        s = np.asarray(sigma[j] if isinstance(sigma, list) else sigma, float)
        cost[j, ~scene] = largest(pos, s, ~scene)
        if scene.any():
            cost[j, scene] = largest(scene_targets[j], s, scene)
    ok = cost <= k
    big = 1e6
    r, c = linear_sum_assignment(np.where(ok, cost, big))
    good = ok[r, c]
    out[r[good]] = c[good]
    return out


def ospa(a, b, *, c: float, p: float = 2.0) -> float:
    """OSPA distance (Schuhmacher et al. 2008) between point sets a (m, 2) and b (n, 2)."""
    a = np.asarray(a, float).reshape(-1, 2)
    b = np.asarray(b, float).reshape(-1, 2)
    m, n = len(a), len(b)
    if m == 0 and n == 0:
        return 0.0
    if m == 0 or n == 0:
        return float(c)
    if m > n:
        a, b, m, n = b, a, n, m
    d = np.minimum(np.hypot(*(a[:, None, :] - b[None, :, :]).transpose(2, 0, 1)), c) ** p
    r, col = linear_sum_assignment(d)
    return float(((d[r, col].sum() + c ** p * (n - m)) / n) ** (1 / p))


def gospa(a, b, *, c: float, p: float = 2.0) -> float:
    """GOSPA distance with alpha = 2 (Rahmathullah et al. 2017): assignment cost
    min(d, c)^p, each missed or false point c^p / 2."""
    a = np.asarray(a, float).reshape(-1, 2)
    b = np.asarray(b, float).reshape(-1, 2)
    if len(a) == 0 or len(b) == 0:
        return float((c ** p / 2 * (len(a) + len(b))) ** (1 / p))
    d = np.hypot(*(a[:, None, :] - b[None, :, :]).transpose(2, 0, 1))
    cost = np.minimum(d, c) ** p
    r, col = linear_sum_assignment(cost)
    assigned = d[r, col] < c
    total = (np.minimum(d[r, col], c)[assigned] ** p).sum()
    unassigned = len(a) + len(b) - 2 * int(assigned.sum())
    return float((total + c ** p / 2 * unassigned) ** (1 / p))


def score_scan_tracks(tracks, truth, *, windows, scan_times, sigma, k: float = 3.0,
                      cutoff: float | None = None, min_positions: int = 2):
    """Score initiated scan tracks window by window.

    Parameters
    ----------
    tracks : structured ndarray
        ``tables.SCAN_TRACK`` rows (``window_start`` says which window).
    truth : structured ndarray
        ``tables.SCAN_TRUTH`` rows.
    windows : list of (first, last)
        The windows the initiator ran on (inclusive scan numbers).
    scan_times : dict
        Time (s) of every scan number.
    sigma : float or callable
        Measurement sigma; a callable maps (x, y) arrays to per-position sigma (polar).
    k : float
        Matching gate in sigmas.
    cutoff : float, optional
        OSPA / GOSPA cut-off c (default 10 sigma at the origin).

    Returns
    -------
    dict
        ``targets`` (sorted target ids), ``initiated`` (windows x targets, bool),
        ``present`` (same shape), ``n_tracks``, ``n_false`` per window, ``ospa``,
        ``gospa`` per window (positions at the window's last scan), ``speed_error``
        (relative speed error of every matched track).
    """
    targets = np.unique(truth["target"]) if len(truth) else np.zeros(0, np.int64)
    sig0 = float(sigma(np.zeros(1), np.zeros(1))[0]) if callable(sigma) else float(sigma)
    c = 10 * sig0 if cutoff is None else cutoff
    res = {"targets": targets, "initiated": np.zeros((len(windows), len(targets)), bool),
           "present": np.zeros((len(windows), len(targets)), bool),
           "n_tracks": np.zeros(len(windows), np.int64), "n_false": np.zeros(len(windows), np.int64),
           "ospa": np.zeros(len(windows)), "gospa": np.zeros(len(windows)), "speed_error": []}
    for w, (a, b) in enumerate(windows):
        tr = tracks[tracks["window_start"] == a]
        pos, sig, ids, vel = [], [], [], []
        for j, tid in enumerate(targets):
            rows = truth[(truth["target"] == tid) & (truth["scan"] >= a) & (truth["scan"] <= b)]
            if len(rows) < min_positions:
                continue
            rows = rows[np.argsort(rows["scan"])]
            xy = np.column_stack([rows["x"], rows["y"]])
            pos.append(xy)
            sig.append(sigma(xy[:, 0], xy[:, 1]) if callable(sigma) else np.full(len(xy), sig0))
            ids.append(j)
            t = np.array([scan_times[s] for s in rows["scan"]])
            vel.append((np.polyfit(t, xy[:, 0], 1)[0], np.polyfit(t, xy[:, 1], 1)[0])
                       if np.ptp(t) > 0 else (0.0, 0.0))
        res["present"][w, ids] = True
        m = match_lines(tr["rho"], tr["theta"], pos, sigma=sig, k=k)
        res["initiated"][w, np.array(ids, np.int64)[m >= 0]] = True
        res["n_tracks"][w] = len(tr)
        res["n_false"][w] = len(tr) - int((m >= 0).sum())
        for j, ti in enumerate(m):
            if ti >= 0:
                v_true = math.hypot(*vel[j])
                if v_true > 0:
                    res["speed_error"].append(
                        math.hypot(tr["vx"][ti] - vel[j][0], tr["vy"][ti] - vel[j][1]) / v_true)
        # OSPA / GOSPA of track positions at the window's last scan
        tb = scan_times.get(b, None)
        true_last = truth[truth["scan"] == b]
        if tb is not None and len(tr):
            t0 = np.array([scan_times[s] for s in tr["scan_start"]])
            est = np.column_stack([tr["x0"] + tr["vx"] * (tb - t0), tr["y0"] + tr["vy"] * (tb - t0)])
        else:
            est = np.zeros((0, 2))
        tru = np.column_stack([true_last["x"], true_last["y"]])
        res["ospa"][w] = ospa(est, tru, c=c)
        res["gospa"][w] = gospa(est, tru, c=c)
    res["speed_error"] = np.array(res["speed_error"])
    return res


def score_image_tracks(tracks, truth, *, sigma: float = 1.5, k: float = 3.0,
                       frames: tuple | None = None, camera=None):
    """Score ``tables.TRACK`` rows of an image sequence against ``tables.TRUTH``.

    The whole sequence (or ``frames`` = (first, last)) is one window. ``sigma`` is the
    position error of a detection in pixels. A ``scene`` track's line and velocity are
    in scene coordinates (``irdetect.initiate.track_positions``): it is measured against
    the true positions minus the camera's offset C_f of their frames (its rho taken
    back by C_frame_start, the offset its line is given relative to) and the true
    velocity in those coordinates, so ``camera`` (``/camera``: a ``tables.CAMERA`` table
    or an array (T, 2)) is needed when the tracks hold any; without it the line rule
    judged a moving camera's scene tracks against the image positions, and found every
    track of a panning clip false.

    Returns
    -------
    dict
        ``pt`` per target, ``pt_overall``, ``pc``, ``n_tracks``, ``n_false``,
        ``speed_error`` (relative, matched tracks).
    """
    from irdetect.initiate.images import camera_at

    tg = np.unique(truth["target"])
    rho = np.asarray(tracks["rho"], float).copy()
    theta = np.asarray(tracks["theta"], float)
    scene = (np.asarray(tracks["scene"], bool) if "scene" in (tracks.dtype.names or ())
             else np.zeros(len(tracks), bool))
    if scene.any():
        if camera is None:
            raise ValueError("scene tracks need the camera's offsets (/camera)")
        start = camera_at(camera, tracks["frame_start"][scene])
        rho[scene] -= start[:, 0] * np.cos(theta[scene]) + start[:, 1] * np.sin(theta[scene])
    pos, moved = [], []          # per target: image positions, and minus the camera's
    for tid in tg:
        rows = truth[truth["target"] == tid]
        if frames is not None:
            rows = rows[(rows["frame"] >= frames[0]) & (rows["frame"] <= frames[1])]
        rows = rows[np.argsort(rows["frame"])]
        pos.append((rows["frame"].astype(float), np.column_stack([rows["x"], rows["y"]])))
        moved.append((pos[-1][0], pos[-1][1] - camera_at(camera, pos[-1][0])
                      if scene.any() else pos[-1][1]))
    m = match_lines(rho, theta, [xy for _, xy in pos], sigma=sigma, k=k, scene=scene,
                    scene_targets=[xy for _, xy in moved])
    err = []
    for j, ti in enumerate(m):
        if ti >= 0:
            f, xy = (moved if scene[ti] else pos)[j]
            v = ((np.polyfit(f, xy[:, 0], 1)[0], np.polyfit(f, xy[:, 1], 1)[0])
                 if len(f) > 1 else (0.0, 0.0))
            err.append(math.hypot(tracks["vx"][ti] - v[0], tracks["vy"][ti] - v[1])
                       / max(math.hypot(*v), 1e-12))
    n_false = len(tracks) - int((m >= 0).sum())
    return {"targets": tg, "pt": (m >= 0).astype(float),
            "pt_overall": float((m >= 0).mean()) if len(tg) else float("nan"),
            "pc": n_false / len(tracks) if len(tracks) else 0.0,
            "n_tracks": len(tracks), "n_false": n_false, "speed_error": np.array(err)}


def assign_paths(share, spans, min_fraction: float = 0.8) -> tuple[np.ndarray, np.ndarray]:
    """The path rule's assignment of tracks to targets.

    Targets and the tracks that follow them are paired one to one (the largest shares
    first, Hungarian). A further track that follows a target (share >= ``min_fraction``)
    is right too when it overlaps that target's right tracks in time by less than half
    its own or their span: the target's track broken in two (a fragment the
    initiation or the tracker started again) follows it, a second track beside the
    first duplicates it and is false.

    Parameters
    ----------
    share : ndarray of shape (n_targets, n_tracks)
        The share of each track's frames in which it lies within the gate of each target.
    spans : ndarray of shape (n_tracks, 2)
        Each track's first and last frame.
    min_fraction : float
        The share a track needs to follow a target (80 %, issue 16).

    Returns
    -------
    matched : ndarray of bool, shape (n_targets,)
        Targets a track follows.
    right : ndarray of bool, shape (n_tracks,)
        Tracks that follow a target; the others (none followed, or a duplicate) are false.

    Examples
    --------
    >>> share = np.array([[1.0, 0.9, 0.9, 0.1]])
    >>> spans = np.array([[0, 49], [50, 99], [10, 40], [0, 99]])
    >>> assign_paths(share, spans)[1].tolist()       # a fragment, a duplicate, clutter
    [True, True, False, False]
    """
    share = np.asarray(share, float)
    spans = np.asarray(spans, float).reshape(-1, 2)
    ok = share >= min_fraction
    matched = np.zeros(share.shape[0], bool)
    right = np.zeros(share.shape[1], bool)
    if not share.size:
        return matched, right
    r, c = linear_sum_assignment(np.where(ok, -share, 1.0))
    keep = ok[r, c]
    matched[r[keep]] = True
    right[c[keep]] = True
    owner = np.full(share.shape[1], -1)
    owner[c[keep]] = r[keep]
    length = spans[:, 1] - spans[:, 0] + 1
    followed = np.where(ok, share, -1.0)               # (targets, tracks)
    best, target = followed.max(axis=0), followed.argmax(axis=0)
    for k in np.argsort(-best, kind="stable"):         # the unpaired, largest share first
        if right[k] or best[k] < 0:
            continue
        j = int(target[k])
        mine = np.flatnonzero(owner == j)
        overlap = (np.minimum(spans[mine, 1], spans[k, 1])
                   - np.maximum(spans[mine, 0], spans[k, 0]) + 1)
        if np.all(overlap < 0.5 * np.minimum(length[mine], length[k])):
            right[k] = matched[j] = True
            owner[k] = j
    return matched, right


def score_track_paths(tracks, truth, *, gate: float, min_fraction: float = 0.8,
                      camera=None) -> dict:
    """Score ``tables.TRACK`` rows of an image sequence by their path in space and time.

    A track's position in frame f is (x0 + vx (f - frame_start), y0 + vy (f -
    frame_start)) (x = column, y = row, px) for f in [frame_start, frame_end], plus the
    camera's motion since frame_start for a ``scene`` track
    (``irdetect.initiate.track_positions``). It follows a target when it lies within
    ``gate`` px of the target's true position in at least ``min_fraction`` of its frames
    (80 %, issue 16's path rule; 50 % before); tracks and targets are then assigned
    (``assign_paths``: one to one, the largest shares first, and beside that a fragment
    of the target's track that does not overlap it in time). Unlike the line rule of
    ``score_image_tracks`` it checks where along its line the track is, and it holds a
    target that wiggles about a straight path (a real target under camera jitter), which
    the line rule's largest distance over every position rejects.

    Parameters
    ----------
    tracks : structured ndarray
        ``tables.TRACK`` rows.
    truth : structured ndarray
        ``tables.TRUTH`` rows (frame, target, x, y).
    gate : float
        Distance in px.
    min_fraction : float
        Share of the track's frames it must lie within ``gate``.
    camera : CAMERA table or ndarray of shape (T, 2), optional
        The camera's offsets (``/camera``), for ``scene`` tracks.

    Returns
    -------
    dict
        ``targets``, ``pt`` (1 per followed target), ``pt_overall``, ``n_tracks``,
        ``n_false`` (tracks that follow no target, or a target another track follows over
        the same frames) and
        ``false_ids`` (their ``track_id``, ascending).
    """
    tg = np.unique(truth["target"])
    n = len(tracks)
    share = np.zeros((len(tg), n))
    span = (tracks["frame_end"] - tracks["frame_start"] + 1).astype(float)
    from irdetect.initiate import track_positions

    for j, tid in enumerate(tg):                           # a handful of targets
        rows = truth[truth["target"] == tid]
        dt = rows["frame"][:, None] - tracks["frame_start"][None, :]          # (rows, n)
        inside = (rows["frame"][:, None] <= tracks["frame_end"][None, :]) & (dt >= 0)
        pos = track_positions(tracks, rows["frame"], camera)                  # (n, rows, 2)
        d = np.hypot(pos[..., 0].T - rows["x"][:, None], pos[..., 1].T - rows["y"][:, None])
        share[j] = (inside & (d <= gate)).sum(axis=0) / np.maximum(span, 1.0)
    matched, right = assign_paths(
        share, np.column_stack([tracks["frame_start"], tracks["frame_end"]]), min_fraction)
    return {"targets": tg, "pt": matched.astype(float),
            "pt_overall": float(matched.mean()) if len(tg) else float("nan"),
            "n_tracks": n, "n_false": n - int(right.sum()),
            "false_ids": sorted(int(i) for i in tracks["track_id"][~right])}


def _summary(targets, pt, pc, n_tracks, n_false, speed_error) -> dict:
    out = {f"pt target {int(t)}": float(v) for t, v in zip(targets, pt)}
    out.update({"pt_overall": float(np.mean(pt)) if len(pt) else float("nan"),
                "pc": float(pc), "n_tracks": int(n_tracks), "n_false": int(n_false),
                "speed_error_median": float(np.median(speed_error)) if len(speed_error)
                else float("nan"),
                "speed_error_max": float(np.max(speed_error)) if len(speed_error)
                else float("nan")})
    return out


def evaluate_image_tracks(results, truth, *, sigma: float | None = None,
                          gate: float = 3.0) -> dict:
    """Scores of the ``/tracks`` of an ``irdetect process`` results file.

    Parameters
    ----------
    results : irdetect.io.Results
        Results holding ``/tracks`` (``tables.TRACK``).
    truth : structured ndarray
        ``tables.TRUTH`` rows of the sequence.
    sigma : float, optional
        Detection position error in px (default: the run's ``initiate.sigma``, else 1.5).
    gate : float
        The detection gate in px; the path rule (``score_track_paths``) takes 2 x gate
        in 80 % of a track's frames.

    Returns
    -------
    dict
        ``pt target N`` (1 when target N is initiated), ``pt_overall``, ``pc``,
        ``n_tracks``, ``n_false``, ``speed_error_median`` / ``_max`` (relative) by the
        line rule; ``pt_path``, ``n_false_path`` and ``false_path_tracks`` (the false
        tracks' ids, to look up in ``/tracks``) by the path rule.
    """
    if sigma is None:
        sigma = float(results.config.get("initiate", {}).get("sigma", 1.5))
    camera = results["camera"] if "camera" in results else None
    s = score_image_tracks(results["tracks"], truth, sigma=sigma, camera=camera)
    path = score_track_paths(results["tracks"], truth, gate=2 * gate, camera=camera)
    return {**_summary(s["targets"], s["pt"], s["pc"], s["n_tracks"], s["n_false"],
                       s["speed_error"]),
            "pt_path": path["pt_overall"], "n_false_path": path["n_false"],
            "false_path_tracks": path["false_ids"]}


def scan_tracks_of(results, *, warn: bool = True):
    """The scan tracks of an ``irdetect initiate`` results file, or None: ``/tracks``
    with ``scan_start`` (the contract), else the deprecated ``/scan_tracks`` (files of
    irdetect before issue 17; read for one release)."""
    if "tracks" in results and "scan_start" in (results["tracks"].dtype.names or ()):
        return results["tracks"]
    if "scan_tracks" in results:
        if not warn:
            return results["scan_tracks"]
        import logging
        logging.getLogger(__name__).warning(
            "%s: /scan_tracks is deprecated (irdetect initiate now writes /tracks); read "
            "for one more release", results.path)
        return results["scan_tracks"]
    return None


def evaluate_scan_results(results, truth_path=None) -> dict:
    """Scores of the scan ``/tracks`` of an ``irdetect initiate`` results file
    (``scan_tracks_of``).

    Truth: the scans file ``truth_path`` (its ``/truth``), else the results' own
    ``/scan_truth``, else the ``/truth`` of the input scans file. Windows, scan times and
    the measurement error come from the results' attributes (``windows``, ``scan_times``,
    ``sigma`` or ``sigma_range`` / ``sigma_azimuth`` for polar scans).

    Returns
    -------
    dict
        ``pt target N`` (share of windows in which target N is initiated), ``pt_overall``,
        ``pc``, ``n_tracks``, ``n_false``, ``ospa_mean``, ``gospa_mean`` (m, at each
        window's last scan), ``speed_error_median`` / ``_max`` (relative).

    Raises
    ------
    InputError
        No truth, or attributes missing (not written by ``irdetect initiate``).
    """
    import json
    from pathlib import Path

    from irdetect.errors import InputError
    from irdetect.io.scans import read_scans

    truth = None
    if truth_path is not None:
        truth = read_scans(truth_path)[1]
        if truth is None:
            raise InputError("has no /truth to score against", truth_path)
    elif "scan_truth" in results:
        truth = results["scan_truth"]
    else:
        name = results.attrs.get("input")
        for path in filter(None, [name and Path(name), name and Path(results.path).parent / name]):
            if path.exists():
                truth = read_scans(path)[1]
                break
        if truth is None:
            raise InputError("no --truth given and neither the results nor their input "
                             "hold scan truth", results.path)
    attrs = results.attrs
    try:
        windows = [tuple(w) for w in json.loads(attrs["windows"])]
        scan_times = {int(k): float(v) for k, v in json.loads(attrs["scan_times"]).items()}
    except (KeyError, ValueError):
        raise InputError("lacks the windows / scan_times attributes of irdetect initiate",
                         results.path) from None
    sr, sa = attrs.get("sigma_range"), attrs.get("sigma_azimuth")
    if sr is not None and sa is not None and float(sa) > 0:
        def sigma(x, y):
            return np.maximum(float(sr), np.hypot(x, y) * float(sa))
    else:
        sigma = float(attrs.get("sigma", results.config.get("initiate", {}).get("sigma", 1.0)))
    res = score_scan_tracks(scan_tracks_of(results), truth, windows=windows,
                            scan_times=scan_times, sigma=sigma)
    present = res["present"].sum(axis=0)
    pt = res["initiated"].sum(axis=0) / np.maximum(present, 1)
    n_tr, n_f = int(res["n_tracks"].sum()), int(res["n_false"].sum())
    out = _summary(res["targets"], pt, n_f / n_tr if n_tr else 0.0, n_tr, n_f,
                   res["speed_error"])
    out["pt_overall"] = float(res["initiated"].sum() / max(res["present"].sum(), 1))
    out["ospa_mean"] = float(res["ospa"].mean()) if len(windows) else float("nan")
    out["gospa_mean"] = float(res["gospa"].mean()) if len(windows) else float("nan")
    return out
