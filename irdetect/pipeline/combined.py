"""The combined-frame path (Wan & Askar 2008 with irdetect's fast band and verification):
one window's suppression, combined frames, directional detection and fusion (``front``),
the correlation of 3 windows (``correlate_windows``) and the candidates that wait for it
(``Pending``). ``irdetect.pipeline`` alone knows the order in which they run.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import asdict

import cv2
import numpy as np
from scipy.spatial import cKDTree

from irdetect import tables
from irdetect.binning import check_bin
from irdetect.combine import combine
from irdetect.config import ProcessConfig
from irdetect.correlate import Correlation, correlate
from irdetect.detect import detect
from irdetect.exclude import excluded
from irdetect.fuse import fuse
from irdetect.peaks import frame_level, frame_peaks
from irdetect.operating import integrated_map, map_threshold, significance
from irdetect.pipeline.fusion import (along_track, dilated_sum, registered_mean, track_mean,
                                      track_values)
from irdetect.pipeline.timing import lap
from irdetect.suppress import suppress
from irdetect.verify import DP_LEADS, Evidence, matched_frame, noise_level, standardise


def correlate_windows(triple, cc, params: "StageParams", timings: dict | None):
    """The correlation of 3 pending windows (``correlate`` with their evidence), per band:
    the paper's band in image coordinates, the fast band's points, tracks and evidence
    in scene coordinates (image minus the camera's offset). Returns one Correlation
    whose rows index the windows' whole tables and whose positions are image
    coordinates."""
    t0 = time.perf_counter()
    evidence = evidence_of(triple, cc)
    # frames between the windows: ``step``, and fewer to the tail window
    # (``CombineConfig.tail``), which ends the sequence
    steps = [int(b.start - a.start) for a, b in zip(triple, triple[1:])]
    parts = [band_correlation(triple, 0, steps, evidence, params.correlate)]
    if params.fast:
        frames, cam = triple_camera(triple)
        shift = None if evidence is None else cam[np.searchsorted(frames, evidence.index)]
        scene = None if evidence is None else dataclasses.replace(
            evidence, shift=shift, leads=FAST_LEADS)
        parts.append(band_correlation(triple, 1, steps, scene, params.fast_correlate, cc.length))
        if params.scene and any((p.table["band"] == 2).any() for p in triple):
            slow = None if evidence is None else dataclasses.replace(evidence, shift=shift)
            parts.append(band_correlation(triple, 2, steps, slow, params.correlate, cc.length))
    corr = parts[0] if len(parts) == 1 else Correlation(
        segments=np.concatenate([c.segments for c in parts]),
        index=np.concatenate([c.index for c in parts]),
        positions=np.concatenate([c.positions for c in parts]),
        significance=np.concatenate([c.significance for c in parts]))
    lap(timings, "correlate", t0)
    return corr


#: the fast band's merit keeps a target near its position in the window's last frame
#: (its wide dilations do not let the path's past outweigh the present): the search of
#: the verification starts 0 and 1 frame of motion ahead of the fused points (0, 0.5, 1,
#: 2 found the same targets on the simulator at twice the cost)
FAST_LEADS = (0.0, 1.0)


#: the bands whose merit follows the camera and whose chains are in scene coordinates:
#: the fast band (1) and the paper's band following the camera (2, ``fast.scene``)
SCENE_BANDS = (1, 2)


def triple_camera(triple) -> tuple[np.ndarray, np.ndarray]:
    """(frames (F,), offsets (F, 2)): the camera's offsets of the 3 windows' frames."""
    frames = np.concatenate([np.arange(p.start, p.start + len(p.camera)) for p in triple])
    return frames, np.concatenate([p.camera for p in triple])


def band_correlation(triple, band: int, steps, evidence, kwargs, length: int = 0) -> Correlation:
    """``correlate`` on one band's points of 3 windows, ``steps`` frames apart (2 ints:
    window 1 to 2, window 2 to 3). Bands 1 and 2 are in scene
    coordinates: their points (the merit's, in the image of each window's last frame)
    lose that frame's camera offset, and their verified positions get the offset at
    their report time."""
    rows = [np.flatnonzero(p.table["band"] == band) for p in triple]
    tables_ = [p.table[r] for p, r in zip(triple, rows)]
    if band in SCENE_BANDS:
        for t, p in zip(tables_, triple):
            t["x"] -= p.camera[length - 1, 0]
            t["y"] -= p.camera[length - 1, 1]
    corr = correlate(*tables_, steps[0], evidence, gap=steps[1], **kwargs)
    index = np.column_stack([r[corr.index[:, i]] for i, r in enumerate(rows)]) \
        if len(corr.index) else corr.index
    positions, segments = corr.positions, corr.segments
    if band in SCENE_BANDS and len(segments):
        frames, cam = triple_camera(triple)
        positions = positions.copy()
        for i, (p, (fx, fy)) in enumerate(zip(triple, (("x1", "y1"), ("x2", "y2"),
                                                       ("x3", "y3")))):
            at = p.start + (length - 1) / 2.0
            positions[:, i, 0] += np.interp(at, frames, cam[:, 0])
            positions[:, i, 1] += np.interp(at, frames, cam[:, 1])
            segments[fx] += p.camera[length - 1, 0]
            segments[fy] += p.camera[length - 1, 1]
        # image velocity: the scene's plus the camera's mean motion over the windows
        span = max(1, frames[-1] - frames[0])
        segments["vx"] += (cam[-1, 0] - cam[0, 0]) / span
        segments["vy"] += (cam[-1, 1] - cam[0, 1]) / span
    return Correlation(segments=segments, index=index, positions=positions,
                       significance=corr.significance)


class StageParams:
    """The stages' keyword arguments, built once per run (not per window)."""

    def __init__(self, config: ProcessConfig):
        self.suppress = asdict(config.suppress)
        # the pipeline picks the long-memory frames; suppress takes the frames
        self.long_memory = self.suppress.pop("long_memory")
        if int(self.long_memory) != self.long_memory or self.long_memory < 0:
            raise ValueError(f"suppress.long_memory must be an integer >= 0, "
                             f"got {self.long_memory!r}")
        # the reader measures the camera's gain control and undoes it
        self.gain_step = self.suppress.pop("gain_step")
        # the driver bins the frames before they are read (``irdetect.binning``)
        self.bin = check_bin(self.suppress.pop("bin"))
        self.combine = {**asdict(config.combine), "step": config.combine.length}
        self.detect = asdict(config.detect)
        self.fuse = asdict(config.fuse)
        self.correlate = asdict(config.correlate)
        # the fast band: the same stages with a wide merit that follows the camera, a
        # point test on it and chains in scene coordinates (needs the dp projection and
        # the verification, which controls its loose first stage's false alarms)
        fast = config.fast
        self.fast = (fast.radius > 0 and config.combine.projection == "dp"
                     and config.correlate.verify > 0)
        self.fast_combine = {**self.combine, "dp_radius": fast.radius}
        self.fast_detect = {**self.detect, "window": 1, "k": fast.k, "sigma": fast.sigma}
        self.fast_fuse = {**self.fuse, "extent": fast.extent}
        self.fast_correlate = {**self.correlate, "max_speed": float(fast.radius),
                               "max_deviation": fast.max_deviation}
        # band 2: the paper's band once more with its merit following the camera, for
        # targets slow against the scene that a moving camera moves in the image
        self.scene = self.fast and fast.scene
        # the per-frame path finds its peaks in the same matched frames
        self.frame = config.frame.enabled
        self.frame_rate = config.frame.false_rate
        # the verification of chains needs the matched residual frames of each window
        self.matched = config.correlate.verify > 0 or self.frame
        self.psf = config.combine.dp_smooth
        # the excluded pixels (irdetect.exclude), set by the driver once the frames'
        # size is known
        self.exclude = None
        # the matched residual's noise scale at least that of the frames' quantisation
        # (``irdetect.verify.quantisation_floor``), set by the driver from the first frame
        self.floor = 0.0



def front(block, previous, params: StageParams, timings: dict | None, following=None,
           camera=None, long_past=None):
    """One window's suppression, combination, detection and fusion (``following``: the
    raw frames after the window that the first frames' background looks ahead to;
    ``camera``: the offsets of previous, block and following; ``long_past``: the
    long-memory frames, ``suppress(long_past=)``).

    Returns (candidates, candidate pixels, matched residual frames (L, H, W) or None,
    the per-frame path's peaks (``tables.FRAME_DETECTION``, frames counted from the
    window's first) or None).
    """
    t = time.perf_counter()
    residual = suppress(block, previous=previous, following=following, camera=camera,
                        long_past=long_past, **params.suppress)
    t = lap(timings, "suppress", t)
    presmoothed = params.matched and params.combine["projection"] == "dp" and params.psf > 0
    if presmoothed:
        # the dp merit and the matched filter smooth with the same Gaussian: smooth each
        # residual once, in place, and tell both stages it is done (same values)
        for r in residual:
            cv2.GaussianBlur(r, (0, 0), params.psf, dst=r, borderType=cv2.BORDER_REFLECT)
    done = {"dp_smooth": 0.0} if presmoothed else {}
    comb = combine(residual, **{**params.combine, **done})[0]
    fast = scene = None
    if params.fast:
        n_prev = 0 if previous is None else len(previous)
        window_camera = None if camera is None else camera[n_prev:n_prev + len(residual)]
        fast = combine(residual, window_camera, **{**params.fast_combine, **done})[0]
        if params.scene and window_camera is not None and camera_outruns(
                window_camera, params.combine["dp_radius"]):
            scene = combine(residual, window_camera, **{**params.combine, **done})[0]
    matched = None
    if params.matched:
        # the residuals become the matched frames in place (no second window of frames)
        smooth = 0.0 if presmoothed else params.psf
        standardise([matched_frame(r, smooth, out=r) for r in residual], floor=params.floor)
        matched = residual
    del residual
    t = lap(timings, "combine", t)
    peaks = None
    if params.frame:
        peaks = frame_peaks(matched, frame_level(matched.shape[1:], params.frame_rate))
        t = lap(timings, "frame", t)
    det = detect(comb, **params.detect)
    det_fast = None if fast is None else detect(fast, **params.fast_detect)
    det_scene = None if scene is None else detect(scene, **params.detect)
    t = lap(timings, "detect", t)
    cand = fuse(det, comb, **params.fuse)
    if fast is not None:
        more = fuse(det_fast, fast, **params.fast_fuse)
        more["band"] = 1
        cand = np.concatenate([cand, more])
    if scene is not None:
        more = fuse(det_scene, scene, **params.fuse)
        more["band"] = 2
        cand = np.concatenate([cand, more])
    if params.exclude is not None:
        cand = cand[~excluded(params.exclude, cand["x"], cand["y"])]
        if peaks is not None:
            peaks = peaks[~excluded(params.exclude, peaks["x"], peaks["y"])]
    lap(timings, "fuse", t)
    return cand, det.count, matched, peaks


def camera_outruns(offsets, radius: float) -> bool:
    """Whether the camera moves the scene, over a window (``offsets`` (L, 2)), by at least
    half the paper's merit's reach (``radius`` px/frame) on average: a target at rest in
    the scene then moves in the image faster than that merit gathers it, and band 2 is
    worth its cost (a still camera, or offsets that follow clouds drifting 0.1 px/frame,
    leave it to band 0)."""
    c = np.asarray(offsets, float)
    return bool(len(c) > 1 and np.hypot(*(c[-1] - c[0])) >= 0.5 * radius * (len(c) - 1))


def evidence_of(pending, cc) -> Evidence | None:
    """The matched frames of the 3 pending windows, each frame once (windows may overlap)."""
    if pending[0].matched is None:
        return None
    blocks, frames, index = [], [], []
    for p in pending:
        # the frames after the last one taken: the window's tail, a block in place
        first = 0 if not index else max(0, index[-1] + 1 - p.start)
        if first < len(p.matched):
            blocks.append(p.matched[first:])
            frames.extend(p.matched[first:])
            index.extend(range(p.start + first, p.start + len(p.matched)))
    # the dp merit's fused point sits near the window's last frame (trailing its target
    # by some frames: DP_LEADS); other projections' at the window's middle
    mid = (cc.length - 1) / 2.0
    dp = cc.projection == "dp"
    at = cc.length - 1 if dp else mid
    return Evidence(frames=blocks, index=np.array(index),
                    times=tuple(p.start + at for p in pending),
                    report=tuple(p.start + mid for p in pending), sigma=noise_level(frames),
                    leads=DP_LEADS if dp else (0.0,))


#: the windows the operating point integrates over: a chain's (the pipeline's
#: ``N_CORRELATE``; the pipeline keeps the last windows' frames for as many)
OPERATING_WINDOWS = 3
#: a combined-frame detection whose median along its track over its own window's frames
#: (the largest matched value within the correlation's ``tolerance`` of each position)
#: is under this share of the largest such median of the ``OPERATING_WINDOWS`` windows
#: is not in its window: the chain's straight path went on where a bright target turned
#: (istd640-seq3-135's last window) or was not yet. A target of constant SNR holds about
#: 1; the noise's 11 x 11 maximum (about 2.6) keeps every chain whose best window reads
#: under 10
OWN_SHARE = 0.25


class Pending:
    """Candidates of one combined frame waiting for the segments that may confirm them."""

    def __init__(self, table: np.ndarray, dp_length: int = 0, matched=None, start: int = 0,
                 tolerance: float = 5.0, camera=None, peaks=None, radius: float = 3.0,
                 false_rate: float = 0.0, exclude=None):
        self.table = table
        # the excluded pixels (H, W) or None: no clutter sample of the operating point
        self.exclude = exclude
        self.false_rate = false_rate  # the operating point's clutter rate (0: none)
        self.peaks = peaks          # the per-frame path's peaks of the window (or None)
        self.radius = radius        # a peak this close to a detection's track supports it
        # the camera's offsets (L, 2) of the window's frames
        self.camera = np.zeros((max(1, dp_length), 2)) if camera is None else camera
        self.tolerance = tolerance  # verified positions this close are one target
        self.dp_length = dp_length
        self.matched = matched      # matched residual frames of the window (or None)
        self._dilated_sum = None
        self.start = start          # the window's first frame
        n = len(table)
        self.vx = np.full(n, np.nan)
        self.vy = np.full(n, np.nan)
        self.pos = np.full((n, 2), np.nan)
        self.seg_score = np.full(n, -np.inf)

    def confirm(self, rows: np.ndarray, segments: np.ndarray, positions=None) -> None:
        """Mark ``rows`` confirmed; keep the velocity (and verified position at the
        window's middle, when given) of the best-scoring segment."""
        if len(rows) == 0:
            return
        self.table["confirmed"][rows] = True
        # several segments may share a point: take them in increasing score so the
        # best one is written last (a loop over a handful of segments)
        for s in np.argsort(segments["score"], kind="stable"):
            r = rows[s]
            if segments["score"][s] >= self.seg_score[r]:
                self.seg_score[r] = segments["score"][s]
                self.vx[r], self.vy[r] = segments["vx"][s], segments["vy"][s]
                if positions is not None:
                    self.pos[r] = positions[s]

    def emit(self, segments: np.ndarray, ahead=(), behind=(), keep_frames: bool = False) -> dict:
        """The window's tables.

        ``ahead`` / ``behind``: the pending windows after it and the emitted ones before
        it whose frames were kept (``keep_frames``), nearest first; they extend the
        operating point's integration (``_operating_point``). Without ``keep_frames`` the
        window's matched frames are released.
        """
        c = self.table
        self._merge_duplicates()
        keep = c["confirmed"]
        det = np.zeros(int(keep.sum()), dtype=tables.DETECTION)
        for name in ("x", "y", "frame_start", "frame_end", "combined_frame", "intensity",
                     "score", "n_members"):
            det[name] = c[name][keep]
        det["vx"], det["vy"] = self.vx[keep], self.vy[keep]
        if self.dp_length:
            # the dp merit puts a target at its position in the window's last frame;
            # report it at the window's middle time like the other projections
            back = (self.dp_length - 1) / 2.0
            det["x"] -= det["vx"] * back
            det["y"] -= det["vy"] * back
        # a verified segment gives the target's position at the window's middle directly
        pos = self.pos[keep]
        ok = np.isfinite(pos[:, 0])
        det["x"][ok], det["y"][ok] = pos[ok, 0], pos[ok, 1]
        det["path"] = tables.PATH_COMBINED
        det["significance"], det["level"] = np.nan, -np.inf
        if self.matched is not None:
            det["snr"], det["support"] = along_track(det, self.matched, self.start,
                                                     self.peaks, self.radius)
            scene = c["band"][keep] == 2
            blocks = self._operating_point(det, ahead, behind, scene)
            # a chain is a straight path over its windows: where the target turned (or
            # left) its position in this window is an extrapolation; the window's own
            # frames tell, read within the correlation's tolerance of the positions
            mid = self.start + (len(self.matched) - 1) / 2.0
            reach = int(round(self.tolerance))
            medians = np.column_stack([np.median(track_values(det, p.start, p.matched, mid,
                                                              reach), axis=1)
                                       for p in blocks])                  # (N, windows)
            absent = medians[:, 0] < OWN_SHARE * medians.max(axis=1)
            c["confirmed"][np.flatnonzero(keep)[absent]] = False
            det = det[~absent]
        if not keep_frames:
            self.matched = self._dilated_sum = None     # release the frames
        return {"candidates": c, "combined_detections": det, "segments": segments}

    def dilated_sum(self) -> np.ndarray:
        """``fusion.dilated_sum`` of the window's matched frames, computed once."""
        if self._dilated_sum is None:
            self._dilated_sum = dilated_sum(self.matched)
        return self._dilated_sum

    def _operating_point(self, det: np.ndarray, ahead, behind, scene=None) -> None:
        """``significance`` and ``level`` of the window's detections on the integrated
        map of ``OPERATING_WINDOWS`` windows: this one and the next ones a chain from it
        spans, or the ones before it at the sequence's end (those that do not overlap
        it): the 36 frames the verification summed, so a target integrates as it did
        there while residue that persists keeps its spread (``irdetect.operating``).
        The detections of band 2 (``scene``, a mask), whose chains summed in scene
        coordinates at the paper's slow speeds, are also judged on the map of those
        frames moved with the camera (``fusion.registered_mean``): structure at rest in
        the scene persists there as it does along such a chain,
        and a map fixed in the image smears it. Their significance is read on that map
        and their level is the larger of the two maps' (a camera whose offsets
        misregister part of the frame, a zoom, smears that part in the moved map
        instead). Band 1 keeps the map fixed in the image: judged on both, dim fast
        targets lost windows (bench_unseen scene 92, SNR 3: 102 -> 98 of 104 windows).
        Returns those windows (Pending, this one first)."""
        blocks = [self]
        for side in (ahead, behind):
            for p in side:
                if len(blocks) == OPERATING_WINDOWS or p.matched is None:
                    break
                first, last = min(b.start for b in blocks), max(b.start + len(b.matched)
                                                                 for b in blocks)
                if p.start >= last or p.start + len(p.matched) <= first:
                    blocks.append(p)
        frames = sum(len(p.matched) for p in blocks)
        integrated = integrated_map(sum(p.dilated_sum() for p in blocks) / frames)
        n = len(self.matched)
        along = track_mean(det, [(p.start, p.matched) for p in blocks],
                           self.start + (n - 1) / 2.0)
        det["significance"] = significance(integrated, along, det["x"], det["y"])
        # the rate is per frame of this window: the window's detections are judged on its
        # own map, and a structure that persists is a false detection in every window whose
        # map holds it, so a map allows the maxima of its window's n frames, not of the
        # OPERATING_WINDOWS x as many it integrates
        if self.false_rate > 0:
            det["level"] = map_threshold(self._scene_only(integrated[0]), self.false_rate, n)
        if scene is not None and scene.any():       # band 2 ran: the camera moved
            # the map moved to the image of the window's middle frame
            ref = 0.5 * (self.camera[(n - 1) // 2] + self.camera[n // 2])
            moved = integrated_map(registered_mean([(p.matched, p.camera[:len(p.matched)])
                                                    for p in blocks], ref))
            det["significance"][scene] = significance(moved, along[scene], det["x"][scene],
                                                      det["y"][scene])
            if self.false_rate > 0:
                det["level"][scene] = np.fmax(det["level"][scene], map_threshold(
                    self._scene_only(moved[0]), self.false_rate, n))
        return blocks

    def _scene_only(self, z: np.ndarray) -> np.ndarray:
        """``z`` (H, W) with the excluded pixels (``irdetect.exclude``) at 0: a burned-in
        overlay's residue is no sample of the clutter the operating level stands for
        (its changing digits raised daub-data13-a's level from 3 to 17-27 sigmas)."""
        return z if self.exclude is None else np.where(self.exclude, np.float32(0), z)

    def _merge_duplicates(self) -> None:
        """One target split into two fused points, each confirmed by a different segment
        (windows k-2..k and k-1..k+1), is one detection: of two confirmed points whose
        verified positions lie within ``tolerance`` px, the lower-scoring is unconfirmed,
        and a point of band 2 (the paper's band following the camera) against one of
        another band: band 2 is there for the targets the others miss, and where both
        see one the paper's own band keeps it (its operating point reads the map it
        integrated in)."""
        rows = np.flatnonzero(self.table["confirmed"] & np.isfinite(self.pos[:, 0]))
        if len(rows) < 2:
            return
        pairs = cKDTree(self.pos[rows]).query_pairs(self.tolerance, output_type="ndarray")
        other = self.table["band"] != 2

        def rank(r):
            return other[r], self.seg_score[r]

        for a, b in pairs:          # a loop over duplicate pairs (rare)
            ra, rb = rows[a], rows[b]
            if not (self.table["confirmed"][ra] and self.table["confirmed"][rb]):
                continue
            self.table["confirmed"][rb if rank(ra) >= rank(rb) else ra] = False
