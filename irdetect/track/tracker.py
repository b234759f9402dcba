"""Frame-by-frame multi-target trackers: FCM association + adaptive PMHT, and a CV Kalman + GNN baseline.

Both trackers take, frame after frame, the candidate regions of :mod:`irdetect.track.regions`
and share one constant-velocity Kalman model and one track management (birth after M-of-N
confirmation, coasting through misses, death, merging; beyond the paper, a track also
started from three regions of three frames on a line, ``max_speed``: a target faster than
a new track's gate). They differ in association and process noise:

* :class:`FCMPMHTTracker` (Cheng et al.): fuzzy c-means memberships of the regions to the
  predicted tracks over a weighted, normalised feature distance (grey, area, position, and
  motion direction once a track is 3 frames old), a noise cluster for "no track", the most
  probable hypothesis per region, a PMHT synthetic measurement per track, the adaptive process
  noise Q(k) = Q0 + dQ(k) with the paper's sign rule, and merge / split handling that keeps
  both ids through a merge.
* :class:`GNNTracker`: Mahalanobis gating and global nearest neighbour assignment
  (``scipy.optimize.linear_sum_assignment``), fixed Q = Q0, no merge handling.

State is [x, vx, y, vy] (x = column, y = row, pixels; velocities in pixels per frame
interval). Output rows are :data:`irdetect.tables.TRACK_POINT`; summaries
:data:`irdetect.tables.TRACK`.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from irdetect import tables
from irdetect.track.fcm import fcm_memberships

_H = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])


#: a tentative track that ``ClutterTest.significant`` finds still unlike clutter lives up
#: to this many ``confirm_window``s before it ends unconfirmed (``irdetect.track.confirm``)
SLOW_LIFE = 2
#: sigmas of the three-point start's gate on the second difference of its positions
GATE_CHAIN = 3.0


@dataclass
class Track:
    """One track's state between frames (read-only for callers)."""

    track_id: int
    x: np.ndarray                     # [x, vx, y, vy]
    P: np.ndarray                     # 4x4 covariance
    dQ: np.ndarray                    # adaptive part of the process noise
    grey: float
    area: float
    born: int                         # frame of birth
    confirmed: bool = False
    hits: int = 1
    misses: int = 0                   # consecutive misses
    merged: int = 0                   # consecutive frames inside a shared region
    last_hit: int = 0
    pending: list = field(default_factory=list)   # points not yet released
    sums: np.ndarray = field(default_factory=lambda: np.zeros(11))
    first_frame: int = -1             # first and last released point
    last_frame: int = -1
    dead: bool = False                # ended by association (absorbed or duplicate)
    # its hits while tentative: frame, x, y, the camera's offset dx, dy, the region's contrast
    meas: list = field(default_factory=list)
    clutter: int = 0                  # other regions near its predictions while tentative
    zbar: np.ndarray | None = None    # its last synthetic measurement (x, y)
    three_point: bool = False         # started from three regions in a line

    @property
    def position(self) -> tuple[float, float]:
        return float(self.x[0]), float(self.x[2])


class _TrackerBase:
    """Kalman model and track management shared by both trackers."""

    def __init__(self, *, frame_interval: float = 1.0, q0: float = 1e-3, r: float = 0.5,
                 gate: float = 4.0, confirm_hits: int = 3, confirm_window: int = 5,
                 max_misses: int = 12, max_tracks: int = 50, init_speed: float = 2.0,
                 feature_memory: float = 0.9, max_birth_area: float = np.inf,
                 confirm=None, max_speed: float = 0.0, lost_clutter: float = 1.0):
        checks = {"frame_interval": frame_interval, "q0": q0, "r": r, "gate": gate,
                  "init_speed": init_speed}
        for name, value in checks.items():
            if not value > 0:
                raise ValueError(f"{name} must be > 0, got {value!r}")
        if not 1 <= confirm_hits <= confirm_window:
            raise ValueError(f"need 1 <= confirm_hits <= confirm_window, got "
                             f"{confirm_hits!r}, {confirm_window!r}")
        if max_misses < 0:
            raise ValueError(f"max_misses must be >= 0, got {max_misses!r}")
        if max_tracks < 1:
            raise ValueError(f"max_tracks must be >= 1, got {max_tracks!r}")
        if not lost_clutter > 0:
            raise ValueError(f"lost_clutter must be > 0, got {lost_clutter!r}")
        if not 0 <= feature_memory < 1:
            raise ValueError(f"feature_memory must be in [0, 1), got {feature_memory!r}")
        T = float(frame_interval)
        self.F = np.array([[1, T, 0, 0], [0, 1, 0, 0], [0, 0, 1, T], [0, 0, 0, 1.0]])
        self.G = np.array([[T * T / 2, 0], [T, 0], [0, T * T / 2], [0, T]])
        self.Q0 = q0 * self.G @ self.G.T
        self.R = r * r * np.eye(2)
        self.T = T
        self.gate = float(gate)
        self.confirm_hits, self.confirm_window = int(confirm_hits), int(confirm_window)
        self.max_misses, self.max_tracks = int(max_misses), int(max_tracks)
        self.lost_clutter = float(lost_clutter)
        self._n_regions = self._n_frames = 0     # seen so far: the regions' density
        self.init_speed = float(init_speed)
        self.feature_memory = float(feature_memory)
        self.max_birth_area = float(max_birth_area)
        if not (math.isfinite(max_speed) and max_speed >= 0):
            raise ValueError(f"max_speed must be a number >= 0, got {max_speed!r}")
        # three-point starts up to this speed (px/frame; 0: none, ``_three_point_starts``),
        # their gate on the second difference of three positions (px)
        self.max_speed = float(max_speed)
        self.chain_gate = GATE_CHAIN * math.sqrt(6.0) * float(r)
        # the clutter test of confirmation (``irdetect.track.confirm.ClutterTest``); None:
        # the M-of-N rule alone
        self.confirm = confirm
        self.tracks: list[Track] = []
        self._ended: list[Track] = []
        # tentative tracks that ended unconfirmed, the latest ``max_tracks``
        self._lapsed: deque[Track] = deque(maxlen=self.max_tracks)
        self._offset = (0.0, 0.0)         # the camera's offset of the frame being stepped
        self._next_id = 1

    # -- the frame step ------------------------------------------------------------------
    def predicted(self) -> np.ndarray:
        """Where the confirmed tracks will be in the next ``step``'s frame: their predicted
        positions (n, 2) = (x, y) px, in the coordinates of the regions (scene coordinates
        when the regions are)."""
        pos = [self.F @ t.x for t in self.tracks if t.confirmed and not t.dead]
        return np.array([[p[0], p[2]] for p in pos]).reshape(-1, 2)

    def step(self, frame: int, regions: np.ndarray, shape: tuple[int, int],
             offset=(0.0, 0.0), seeds: np.ndarray | None = None) -> np.ndarray:
        """Advance all tracks by one frame.

        Parameters
        ----------
        frame : int
            Index of this frame (increasing by one per call).
        regions : ndarray of dtype :data:`irdetect.track.regions.REGION`
            This frame's candidate regions (x = column, y = row, pixels).
        shape : (H, W)
            Frame size; a track predicted outside it (beyond ``gate`` pixels) ends.
        offset : (float, float)
            The camera's offset (x, y px) of this frame when the regions and tracks are in
            scene coordinates (image minus offset, ``irdetect.camera``); the image's bounds
            are then shifted by it. (0, 0): image coordinates.
        seeds : ndarray of bool, shape (len(regions),), optional
            The regions that may start a track and count as this frame's clutter (default
            all); the others (peaks found below the frame's level near a confirmed track's
            prediction, ``irdetect.track.detector.guided_regions``) only feed tracks.

        Returns
        -------
        ndarray of dtype TRACK_POINT
            Points released by this step: confirmed tracks' estimates of this frame, plus
            earlier points held back while a track was tentative or coasting (a coasted run is
            released when the track is seen again and dropped when it dies).
        """
        out: list[tuple] = []
        for t in self.tracks:
            self._predict(t)
        h, w = shape
        margin = self.gate
        alive = []
        ox, oy = float(offset[0]), float(offset[1])
        self._offset = (ox, oy)
        for t in self.tracks:
            px, py = t.position
            px, py = px + ox, py + oy
            if -margin <= px <= w - 1 + margin and -margin <= py <= h - 1 + margin:
                alive.append(t)
            else:
                self._end(t)
        self.tracks = alive
        z = np.column_stack([regions["x"], regions["y"]]) if len(regions) else np.zeros((0, 2))
        seeds = np.ones(len(z), bool) if seeds is None else np.asarray(seeds, bool)
        self._n_regions += int(seeds.sum())
        self._n_frames += 1
        self._end_lost(self._n_regions / (self._n_frames * h * w))
        assign, shared, blocked = self._associate(regions, z)
        if self.confirm is not None:
            self._count_clutter(z, assign, seeds)
            self.confirm.observe(int(seeds.sum()))
        for i, t in enumerate(list(self.tracks)):
            rows = assign[i]
            if i in shared:
                t.merged += 1
                t.misses = 0
                self._record(t, frame, None, out, coasting=False, measured=False)
            elif len(rows):
                wts = rows[1]
                self._update(t, z[rows[0]], wts, regions[rows[0]])
                if not t.confirmed:
                    t.meas.append((frame, t.zbar[0], t.zbar[1]) + self._offset
                                  + (float(regions["contrast"][rows[0]].max()),))
                t.hits += 1
                t.misses = 0
                t.merged = 0
                t.last_hit = frame
                self._record(t, frame, regions[rows[0]], out, coasting=False)
            else:
                t.misses += 1
                t.merged = 0
                self._record(t, frame, None, out, coasting=True)
        blocked = blocked | ~seeds
        if self.max_speed > 0:
            blocked |= self._three_point_starts(frame, regions, z, blocked)
        self._manage(frame, out)
        self._births(frame, regions, z, blocked)
        return _points(out)

    def finish(self) -> np.ndarray:
        """End every track; returns the TRACK summary table of all confirmed tracks.

        Points still held back (a trailing coasted run) are dropped.
        """
        for t in self.tracks:
            self._end(t)
        self.tracks = []
        # a track confirmed while coasting that is never hit again released no point
        done = sorted((t for t in self._ended if t.confirmed and t.sums[0] > 0),
                      key=lambda t: t.track_id)
        return _summaries(done)

    def _end_lost(self, density: float) -> None:
        """End the confirmed tracks that missed their last frame and whose gate would hold
        ``lost_clutter`` of this sequence's regions or more on average (``density``:
        regions per px^2 per frame so far): a hit there is no likelier the target than
        clutter, and taking it would widen the gate further through the adaptive noise (a
        track coasting 12 frames on istd640-seq3-135's clutter grew to a 4-sigma gate of
        about 100 px, took a region 40 px off, and then jumped up to 177 px a frame). The
        gate of a track is the ellipse e^T S^-1 e <= ``gate``^2, of area
        pi gate^2 sqrt(det S). A track hit every frame is kept."""
        confirmed = [t for t in self.tracks if t.confirmed and t.misses]
        if density <= 0 or not confirmed:
            return
        S = np.array([self._innovation_cov(t) for t in confirmed])
        area = math.pi * self.gate ** 2 * np.sqrt(np.linalg.det(S))
        for t, a in zip(confirmed, area):
            if a * density >= self.lost_clutter:
                self._end(t)
                self.tracks.remove(t)

    # -- Kalman --------------------------------------------------------------------------
    def _process_noise(self, t: Track) -> np.ndarray:
        return self.Q0

    def _predict(self, t: Track) -> None:
        t.x = self.F @ t.x
        t.P = self.F @ t.P @ self.F.T + self._process_noise(t)

    def _innovation_cov(self, t: Track) -> np.ndarray:
        return _H @ t.P @ _H.T + self.R

    def _update(self, t: Track, zs: np.ndarray, wts: np.ndarray, regs: np.ndarray) -> None:
        """PMHT synthetic measurement: weighted mean of the regions, covariance R / sum(w)."""
        wsum = float(np.sum(wts))
        zbar = (wts[:, None] * zs).sum(axis=0) / wsum
        t.zbar = zbar
        Rbar = self.R / min(wsum, 1.0) if wsum < 1 else self.R / wsum
        S = _H @ t.P @ _H.T + Rbar
        e = zbar - _H @ t.x
        self._adapt(t, e, S)
        K = t.P @ _H.T @ np.linalg.inv(S)
        t.x = t.x + K @ e
        t.P = (np.eye(4) - K @ _H) @ t.P
        t.P = 0.5 * (t.P + t.P.T)
        a = self.feature_memory
        t.grey = a * t.grey + (1 - a) * float(np.average(regs["grey"], weights=wts))
        t.area = a * t.area + (1 - a) * float(np.average(regs["area"], weights=wts))

    def _adapt(self, t: Track, e: np.ndarray, S: np.ndarray) -> None:
        """Hook for the adaptive process noise (none in the baseline)."""

    # -- management ----------------------------------------------------------------------
    def _record(self, t: Track, frame: int, regs, out: list, *, coasting: bool,
                measured: bool | None = None) -> None:
        if regs is not None and len(regs):
            area, grey = float(regs["area"].sum()), float(np.average(regs["grey"],
                                                                     weights=regs["area"]))
        else:
            area, grey = t.area, t.grey
        measured = (not coasting) if measured is None else measured
        point = (frame, t.track_id, t.x[0], t.x[2], t.x[1], t.x[3], area, grey, measured)
        t.pending.append(point)
        if t.confirmed and not coasting:
            self._release(t, out)

    def _release(self, t: Track, out: list) -> None:
        for p in t.pending:
            s = t.sums
            f, x, y = p[0], p[2], p[3]
            s += (1, f, f * f, x, y, x * f, y * f, x * x, y * y, x * y, p[8])
            out.append(p[:8])
            if t.first_frame < 0:
                t.first_frame = f
            t.last_frame = f
        t.pending = []

    def _manage(self, frame: int, out: list) -> None:
        keep = []
        test = self.confirm
        sample = None
        if test is not None:
            # the tentative tracks' statistics, then this frame's clutter sample
            test.measure_all([t for t in self.tracks if not t.confirmed and not t.dead],
                             frame)
            sample = test.sample(self.tracks, frame + 1, self.confirm_hits)
        for t in self.tracks:
            age = frame - t.born + 1
            if t.dead:
                self._end(t)
                continue
            if not t.confirmed:
                if t.hits >= self.confirm_hits and (
                        test is None or test.passes(t, sample, frame + 1)):
                    t.confirmed = True
                    if test is not None:
                        self._succeed(t, frame)
                    t.meas = []
                    if t.misses == 0:
                        self._release(t, out)
                elif (age >= self.confirm_window and not (
                        test is not None and age < SLOW_LIFE * self.confirm_window
                        and test.significant(t))) or (
                        t.misses > self.confirm_window - self.confirm_hits if test is None
                        else t.misses > test.misses):
                    if test is not None:
                        test.ended(t, self.confirm_hits)
                    self._end(t)
                    continue
            elif t.misses > self.max_misses:
                self._end(t)
                continue
            keep.append(t)
        self.tracks = [t for t in keep if not t.dead]   # taken over by a successor

    def _succeed(self, t: Track, frame: int) -> None:
        """A newly confirmed track born while a confirmed track coasts near its first hit
        takes that track's id and history (the clutter-tested confirmation only): the
        target jumped out of the old track's gate (a camera jump the offsets missed, a
        centroid that moved) and the old track would end with an id switch. Failing that,
        a tentative track that ended unconfirmed near its first hit gives it its hits: the
        target's first hits, before a jump of the same kind restarted it (easy3's shaking
        camera: 3 frames), are the new track's first points.

        Near: the old track, extrapolated back from ``frame`` at its velocity to the new
        track's first hit, is within the confirmation's ``radius`` px of it, and it was
        last hit before the new track's birth."""
        if not t.meas:
            return
        f0, x0, y0 = t.meas[0][:3]
        best = self._before(t, f0, x0, y0, [
            o for o in self.tracks + self._ended[-self.max_tracks:]
            if o is not t and o.confirmed and not o.dead and o.misses > 0])
        if best is not None:
            t.track_id = best.track_id
            t.pending = [(p[0], best.track_id) + tuple(p[2:]) for p in t.pending]
            t.sums = best.sums.copy()
            t.first_frame = best.first_frame
            if best in self._ended:
                self._ended.remove(best)
            best.confirmed = False          # ends with no summary of its own
            best.dead = True
            return
        best = self._before(t, f0, x0, y0, self._lapsed)
        if best is not None:
            self._lapsed.remove(best)
            t.pending = [(p[0], t.track_id) + tuple(p[2:]) for p in best.pending] + t.pending

    def _before(self, t: Track, f0: int, x0: float, y0: float, tracks) -> Track | None:
        """Of ``tracks``, the one last hit before ``t``'s birth, at most ``max_misses`` + 1
        frames before ``t``'s first hit (frame ``f0`` at x0, y0), whose extrapolation to
        ``f0`` lies nearest to it within the confirmation's radius (None: none)."""
        best, dist = None, self.confirm.radius
        for o in tracks:
            if o.last_hit >= t.born or f0 - o.last_hit > self.max_misses + 1:
                continue
            # its state is predicted to the frame of its last miss
            back = o.last_hit + o.misses - f0
            d = math.hypot(o.x[0] - o.x[1] * back - x0, o.x[2] - o.x[3] * back - y0)
            if d <= dist:
                best, dist = o, d
        return best

    def _end(self, t: Track) -> None:
        if t.confirmed:
            self._ended.append(t)
        elif self.confirm is not None and not t.dead:
            # its measured points up to its last hit, for a successor (``_succeed``)
            t.pending = [p for p in t.pending if p[0] <= t.last_hit]
            self._lapsed.append(t)
            return
        t.pending = []

    def _three_point_starts(self, frame: int, regions: np.ndarray, z: np.ndarray,
                            blocked: np.ndarray) -> np.ndarray:
        """Start tracks from three regions in a line: a target too fast for a new track's
        gate (``init_speed``) leaves a one-hit track in each frame it crosses.

        A one-hit tentative track A born two frames ago at p1 (px, the regions'
        coordinates), one B born last frame at p2 within ``max_speed`` px of it, and a free
        region of this frame at p3 within GATE_CHAIN sqrt(6) r px of the constant-velocity
        prediction 2 p2 - p1 (r the regions' position sigma: the second difference of three
        positions has sigma sqrt(6) r) make one track: A takes the three hits, velocity
        (p3 - p1) / 2 px/frame, and B ends. The closest predictions are taken first; each
        track and region is used once. The tracks so started are tested for confirmation
        as any other.

        Returns
        -------
        ndarray of bool, shape (len(regions),)
            The regions taken.
        """
        taken = np.zeros(len(z), bool)
        young = [t for t in self.tracks
                 if not t.confirmed and not t.dead and len(t.meas) == 1]
        first = [t for t in young if t.born == frame - 2]
        second = [t for t in young if t.born == frame - 1]
        free = self._free(regions, blocked)
        if not first or not second or not len(free):
            return taken
        p1 = np.array([t.meas[0][1:3] for t in first])
        p2 = np.array([t.meas[0][1:3] for t in second])
        pairs = cKDTree(p2).sparse_distance_matrix(cKDTree(p1), self.max_speed,
                                                   output_type="ndarray")
        if not len(pairs):
            return taken
        b, a = pairs["i"], pairs["j"]
        d, k = cKDTree(z[free]).query(2.0 * p2[b] - p1[a],
                                      distance_upper_bound=self.chain_gate)
        hit = np.flatnonzero(np.isfinite(d))
        chains = np.stack([a, b, k])[:, hit[np.argsort(d[hit], kind="stable")]]
        for row in range(3):            # each track and region once, closest first
            chains = chains[:, np.sort(np.unique(chains[row], return_index=True)[1])]
        for ai, bi, ki in chains.T:     # the few starts made
            self._start_from(first[ai], second[bi], frame, regions[free[ki]])
            taken[free[ki]] = True
        return taken

    def _start_from(self, t: Track, other: Track, frame: int, reg) -> None:
        """``t`` (one hit at p1) takes ``other``'s one hit (p2) and the region ``reg`` of
        this frame (p3): three hits on a line (``_three_point_starts``)."""
        x1, y1 = t.meas[0][1:3]
        f2, x2, y2 = other.meas[0][:3]
        x3, y3 = float(reg["x"]), float(reg["y"])
        vx, vy = (x3 - x1) / 2.0, (y3 - y1) / 2.0
        r2 = self.R[0, 0]
        t.x = np.array([x3, vx, y3, vy])
        t.P = np.diag([r2, r2, r2, r2])
        t.meas = [t.meas[0], other.meas[0],
                  (frame, x3, y3) + self._offset + (float(reg["contrast"]),)]
        p = other.pending[0]
        t.pending = [t.pending[0][:4] + (vx, vy) + t.pending[0][6:],
                     (f2, t.track_id, x2, y2, vx, vy) + p[6:],
                     (frame, t.track_id, x3, y3, vx, vy, float(reg["area"]),
                      float(reg["grey"]), True)]
        t.zbar = np.array([x3, y3])
        t.hits, t.misses, t.last_hit = 3, 0, frame
        t.three_point = True
        t.grey = (t.grey + other.grey + float(reg["grey"])) / 3.0
        t.area = (t.area + other.area + float(reg["area"])) / 3.0
        other.dead = True

    def _free(self, regions: np.ndarray, blocked: np.ndarray) -> np.ndarray:
        """Indices of the regions a track may start from: not ``blocked`` (taken or no
        seed) and no larger than ``max_birth_area``."""
        return np.flatnonzero(~blocked & (regions["area"] <= self.max_birth_area))

    def _births(self, frame: int, regions: np.ndarray, z: np.ndarray, blocked: np.ndarray) -> None:
        free = self._free(regions, blocked)
        room = self.max_tracks - len(self.tracks)
        if room <= 0 or len(free) == 0:
            return
        order = free[np.argsort(-(regions["area"][free] * regions["contrast"][free]),
                                kind="stable")][:room]
        s2 = self.init_speed ** 2
        r2 = self.R[0, 0]
        for i in order:
            reg = regions[i]
            t = Track(self._next_id, np.array([reg["x"], 0.0, reg["y"], 0.0]),
                      np.diag([r2, s2, r2, s2]), np.zeros((4, 4)), float(reg["grey"]),
                      float(reg["area"]), born=frame, last_hit=frame)
            self._next_id += 1
            t.pending.append((frame, t.track_id, reg["x"], reg["y"], 0.0, 0.0,
                              float(reg["area"]), float(reg["grey"]), True))
            t.meas.append((frame, float(reg["x"]), float(reg["y"])) + self._offset
                          + (float(reg["contrast"]),))
            self.tracks.append(t)

    def _count_clutter(self, z: np.ndarray, assign, seeds: np.ndarray) -> None:
        """Add to every tentative track the regions of this frame (``seeds``: those found
        at the frame's level) within the clutter test's radius of its prediction that it
        did not take (the local clutter)."""
        tent = [i for i, t in enumerate(self.tracks) if not t.confirmed]
        if not tent or not seeds.any():
            return
        pred = np.array([[self.tracks[i].x[0], self.tracks[i].x[2]] for i in tent])
        near = np.hypot(*(z[seeds][None, :, :] - pred[:, None, :]).transpose(2, 0, 1)) \
            <= self.confirm.radius
        for row, i in enumerate(tent):       # a loop over the tentative tracks
            # the regions it took, of those counted (a gate search's are not)
            own = int(seeds[assign[i][0]].sum()) if len(assign[i]) else 0
            self.tracks[i].clutter += max(int(near[row].sum()) - own, 0)

    def _gate_matrix(self, z: np.ndarray) -> np.ndarray:
        """Squared Mahalanobis distance of each region to each predicted track, (n_t, n_r)."""
        if not self.tracks or len(z) == 0:
            return np.zeros((len(self.tracks), len(z)))
        pred = np.array([[t.x[0], t.x[2]] for t in self.tracks])
        Sinv = np.linalg.inv(np.array([self._innovation_cov(t) for t in self.tracks]))
        e = z[None, :, :] - pred[:, None, :]
        return np.einsum("tri,tij,trj->tr", e, Sinv, e)

    def _associate(self, regions, z):
        raise NotImplementedError


class GNNTracker(_TrackerBase):
    """Constant-velocity Kalman filter with global nearest neighbour association.

    The baseline: squared Mahalanobis distance gated at ``gate`` sigmas, one region per track
    by ``scipy.optimize.linear_sum_assignment``, fixed process noise Q0, no merge handling
    (of two tracks on one merged blob, one coasts). Parameters as :class:`FCMPMHTTracker`.
    """

    def _associate(self, regions, z):
        n_t, n_r = len(self.tracks), len(z)
        assign = [() for _ in range(n_t)]
        blocked = np.zeros(n_r, bool)
        if n_t and n_r:
            d2 = self._gate_matrix(z)
            ok = d2 <= self.gate ** 2
            cost = np.where(ok, d2, 1e12)
            rows, cols = linear_sum_assignment(cost)
            for ti, ri in zip(rows, cols):
                if ok[ti, ri]:
                    assign[ti] = (np.array([ri]), np.array([1.0]))
                    blocked[ri] = True
            confirmed = np.array([t.confirmed for t in self.tracks])
            blocked |= (ok & confirmed[:, None]).any(axis=0)
        return assign, set(), blocked


class FCMPMHTTracker(_TrackerBase):
    """FCM association + adaptive-process-noise PMHT tracker (Cheng et al.).

    Parameters
    ----------
    frame_interval : float
        T of the constant-velocity model (1 = velocities in pixels per frame).
    q0 : float
        Q0 = q0 * G G^T, q0 the acceleration variance in (pixels / T^2)^2.
    r : float
        Measurement noise sigma per axis (pixels).
    adaptive : bool
        Use Q(k) = Q0 + dQ(k); False keeps Q0 (for ablation).
    beta : float
        Memory of dQ, in [0, 1): dQ(k) = beta dQ(k-1) + (1 - beta) G A(k) G^T.
    m : float
        FCM fuzzifier.
    gate : float
        Position gate in sigmas of the innovation (Mahalanobis); also the noise-cluster
        distance: a region farther than ``gate`` (in the weighted feature distance) from every
        track belongs to no track.
    w_position, w_grey, w_area, w_direction : float
        Weights of the squared normalised feature distances in J1 / J2.
    grey_scale : float
        Grey difference (grey levels) counted as one unit of distance.
    grey_relative : float
        With ``grey_relative`` > 0 the unit is at least this fraction of the larger of the
        two greys (the per-frame detector's regions, whose grey is a local SNR that varies
        in proportion to itself from frame to frame); 0: ``grey_scale`` alone.
    area_scale : float
        Relative area difference counted as one unit.
    direction_after : int
        A track with at least this many hits uses J2 (adds the motion direction).
    min_speed : float
        Direction is used only for tracks faster than this (pixels / T).
    confirm_hits, confirm_window : int
        A tentative track is confirmed after ``confirm_hits`` hits within its first
        ``confirm_window`` frames, and dropped otherwise.
    max_misses : int
        A confirmed track ends after more than this many consecutive misses.
    lost_clutter : float
        A confirmed track that missed its last frame also ends, lost, when its gate would
        hold this many of the sequence's regions or more on average (its area times their
        measured density): a hit there is no likelier the target than clutter. inf: never
        (the paper's).
    max_merged : int
        Two tracks may share one region (a merge) for at most this many frames; then the
        younger one ends (a duplicate, not a merge).
    merge_margin : float
        A track shares a region when its prediction lies inside the region's bounding box
        grown by this many pixels. A region holding one confirmed prediction feeds only that
        track (so a target coming out of a merge cannot grab the blob it left).
    max_tracks : int
        Cap on live tracks (tentative included): bounds the work in a glint storm.
    init_speed : float
        Prior velocity sigma of a new track (pixels / T).
    max_speed : float
        Three-point starts up to this speed (px/frame; ``_three_point_starts``); 0: none,
        a track starts from one region alone (the paper's design).
    feature_memory : float
        Exponential memory of a track's grey and area features.
    max_birth_area : float
        Regions larger than this (pixels) feed existing tracks and merges but start no track.
    confirm : irdetect.track.confirm.ClutterTest, optional
        A tentative track with ``confirm_hits`` hits is confirmed only when it also passes
        this test (clutter of the measured density would rarely make a track as good;
        ``irdetect.track.confirm``); None: the M-of-N rule alone. With the test, a track
        confirmed while a confirmed track coasts (or ended coasting up to ``max_misses``
        frames before) within the test's ``radius`` px of its first hit, last hit before
        its birth, takes that track's id and history (a target that jumped out of its
        track's gate).

    Notes
    -----
    The paper's objective functions J1, J2 and its dQ formula are lost in the text. We use
    FCM memberships of the current regions to the *fixed* predicted tracks (no centre update)
    under D^2 = w_p d_p^2 + w_g d_g^2 + w_s d_s^2 [+ w_a d_a^2], with d_p the Mahalanobis
    distance to the prediction, d_g = dg / grey_scale, d_s = ds / (area_scale max(s_track, s_region)) (symmetric, so a
    ship entering the image and growing from a sliver is not lost),
    d_a^2 = 1 - cos(angle between the track velocity and the step to the region), plus a
    noise cluster at distance ``gate``. dQ is driven by the part of the squared innovation
    the filter did not expect: a_x = max(e_x^2 - S_xx, 0) 4 / T^4, likewise a_y, and the
    cross term r sqrt(a_x a_y) with the paper's sign rule r = +1 when e_x e_y > 0 else -1
    (this keeps dQ positive semi-definite). With no surprise dQ decays by ``beta`` per hit,
    so Q grows in a manoeuvre and shrinks back when the target is steady. PMHT without EM
    iterations: one pass, each region goes to its most probable track, and a track's
    measurement is the membership-weighted mean of its regions with covariance R / sum(w).
    """

    def __init__(self, *, adaptive: bool = True, beta: float = 0.9, m: float = 2.0,
                 w_position: float = 1.0, w_grey: float = 1.0, w_area: float = 1.0,
                 w_direction: float = 1.0, grey_scale: float = 20.0, area_scale: float = 0.5,
                 direction_after: int = 3, min_speed: float = 0.2, max_merged: int = 150,
                 merge_margin: float = 1.0, grey_relative: float = 0.0, **common):
        super().__init__(**common)
        if not 0 <= beta < 1:
            raise ValueError(f"beta must be in [0, 1), got {beta!r}")
        if not m > 1:
            raise ValueError(f"m must be > 1, got {m!r}")
        for name, value in {"w_position": w_position, "w_grey": w_grey, "w_area": w_area,
                            "w_direction": w_direction}.items():
            if not value >= 0:
                raise ValueError(f"{name} must be >= 0, got {value!r}")
        if not (grey_scale > 0 and area_scale > 0):
            raise ValueError(f"grey_scale and area_scale must be > 0, got "
                             f"{grey_scale!r}, {area_scale!r}")
        if max_merged < 0 or merge_margin < 0:
            raise ValueError(f"max_merged and merge_margin must be >= 0, got "
                             f"{max_merged!r}, {merge_margin!r}")
        self.adaptive, self.beta, self.m = bool(adaptive), float(beta), float(m)
        self.w = (float(w_position), float(w_grey), float(w_area), float(w_direction))
        self.grey_scale, self.area_scale = float(grey_scale), float(area_scale)
        self.direction_after, self.min_speed = int(direction_after), float(min_speed)
        self.max_merged, self.merge_margin = int(max_merged), float(merge_margin)
        if not grey_relative >= 0:
            raise ValueError(f"grey_relative must be >= 0, got {grey_relative!r}")
        self.grey_relative = float(grey_relative)
        self.last_memberships = np.zeros((0, 0))

    def process_noise(self, t: Track) -> np.ndarray:
        """Q(k) = Q0 + dQ(k) of track ``t`` (4x4, state order [x, vx, y, vy])."""
        return self._process_noise(t)

    def _process_noise(self, t: Track) -> np.ndarray:
        return self.Q0 + t.dQ if self.adaptive else self.Q0

    def _adapt(self, t: Track, e: np.ndarray, S: np.ndarray) -> None:
        if not self.adaptive:
            return
        k = 4.0 / self.T ** 4
        ax = max(e[0] ** 2 - S[0, 0], 0.0) * k
        ay = max(e[1] ** 2 - S[1, 1], 0.0) * k
        r = 1.0 if e[0] * e[1] > 0 else -1.0          # the paper's sign rule
        c = r * np.sqrt(ax * ay)
        A = np.array([[ax, c], [c, ay]])
        t.dQ = self.beta * t.dQ + (1 - self.beta) * (self.G @ A @ self.G.T)

    def _distances(self, regions, z, d2):
        wp, wg, ws, wa = self.w
        grey = np.array([t.grey for t in self.tracks])
        area = np.array([t.area for t in self.tracks])
        D2 = wp * d2
        rg = regions["grey"][None, :]
        unit = self.grey_scale
        if self.grey_relative > 0:
            unit = np.maximum(unit, self.grey_relative * np.maximum(np.abs(rg),
                                                                    np.abs(grey[:, None])))
        D2 = D2 + wg * ((rg - grey[:, None]) / unit) ** 2
        ra = regions["area"][None, :]
        D2 = D2 + ws * ((ra - area[:, None])
                        / (self.area_scale * np.maximum(ra, area[:, None]))) ** 2
        if wa > 0:
            v = np.array([[t.x[1], t.x[3]] for t in self.tracks])
            speed = np.hypot(v[:, 0], v[:, 1])
            use = (np.array([t.hits for t in self.tracks]) >= self.direction_after) \
                & (speed > self.min_speed)
            if use.any():
                prev = np.array([[t.x[0] - t.x[1] * self.T, t.x[2] - t.x[3] * self.T]
                                 for t in self.tracks])
                step = z[None, :, :] - prev[:, None, :]
                norm = np.hypot(step[..., 0], step[..., 1]) * np.maximum(speed, 1e-9)[:, None]
                dot = np.einsum("tri,ti->tr", step, v)
                cos = np.where(norm > 0, dot / np.maximum(norm, 1e-12), 1.0)
                D2 = D2 + wa * np.where(use[:, None], 1.0 - cos, 0.0)
        return D2

    def _associate(self, regions, z):
        n_t, n_r = len(self.tracks), len(z)
        assign = [() for _ in range(n_t)]
        blocked = np.zeros(n_r, bool)
        shared: set[int] = set()
        if n_t == 0 or n_r == 0:
            self.last_memberships = np.zeros((n_t + 1, n_r))
            return assign, shared, blocked
        d2 = self._gate_matrix(z)
        ok = d2 <= self.gate ** 2
        confirmed = np.array([t.confirmed for t in self.tracks])
        # merges: a region whose grown box holds >= 2 confirmed predictions feeds no one, and
        # one that holds exactly one confirmed prediction feeds only that track
        pred = np.array([[t.x[0], t.x[2]] for t in self.tracks])
        mm = self.merge_margin
        inside = ((pred[:, 0:1] >= regions["bx"][None, :] - mm)
                  & (pred[:, 0:1] <= (regions["bx"] + regions["bw"] - 1)[None, :] + mm)
                  & (pred[:, 1:2] >= regions["by"][None, :] - mm)
                  & (pred[:, 1:2] <= (regions["by"] + regions["bh"] - 1)[None, :] + mm))
        owned = (inside & confirmed[:, None]).sum(axis=0) == 1
        foreign = owned[None, :] & ~inside
        D2 = np.where(ok & ~foreign, self._distances(regions, z, d2), np.inf)
        u = fcm_memberships(np.sqrt(D2), m=self.m,
                            noise_distance=self.gate * np.sqrt(max(self.w[0], 1e-12)))
        self.last_memberships = u
        best = np.argmax(u, axis=0)                     # most probable hypothesis per region
        n_inside = (inside & confirmed[:, None]).sum(axis=0)
        shared_regions = n_inside >= 2
        for ri in np.flatnonzero(shared_regions):
            members = np.flatnonzero(inside[:, ri] & confirmed)
            for ti in members:
                shared.add(int(ti))
        if self.max_merged and shared:
            shared = self._resolve_duplicates(shared, inside, shared_regions)
        for ti in range(n_t):
            if ti in shared:
                continue
            rows = np.flatnonzero((best == ti) & ~shared_regions)
            if len(rows):
                assign[ti] = (rows, u[ti, rows])
        blocked |= shared_regions | (best < n_t)
        # a region in a confirmed track's gate, or holding its prediction in its box
        # (its gate may miss the region when the region's centroid jumps), starts no track
        blocked |= ((ok | inside) & confirmed[:, None]).any(axis=0)
        # a tentative track sitting on a confirmed track's region is absorbed
        taken = np.zeros(n_r, bool)
        for ti in range(n_t):
            if confirmed[ti] and len(assign[ti]):
                taken[assign[ti][0]] = True
        taken |= shared_regions
        absorbed = (~confirmed) & (inside & taken[None, :]).any(axis=1)
        if absorbed.any():
            for ti in np.flatnonzero(absorbed):
                self.tracks[ti].dead = True
                assign[ti] = ()
        return assign, shared, blocked

    def _resolve_duplicates(self, shared, inside, shared_regions):
        """End the younger of tracks that have shared a region for more than max_merged frames."""
        for ri in np.flatnonzero(shared_regions):
            members = [ti for ti in np.flatnonzero(inside[:, ri]) if int(ti) in shared]
            old = [ti for ti in members if self.tracks[ti].merged >= self.max_merged]
            if len(old) >= 2:
                keep = min(old, key=lambda ti: self.tracks[ti].track_id)
                for ti in old:
                    if ti != keep:
                        self.tracks[ti].dead = True
                shared.discard(int(keep))
        return shared


def _points(rows: list[tuple]) -> np.ndarray:
    out = np.zeros(len(rows), tables.TRACK_POINT)
    if rows:
        arr = np.array(rows, dtype=float)
        for j, name in enumerate(tables.TRACK_POINT.names):
            out[name] = arr[:, j]
    return out


def _summaries(done: list[Track]) -> np.ndarray:
    out = tables.from_columns(tables.TRACK, n=len(done))
    for i, t in enumerate(done):
        n, sf, sff, sx, sy, sxf, syf, sxx, syy, sxy, meas = t.sums
        fm, xm, ym = sf / n, sx / n, sy / n
        vf = sff / n - fm * fm
        vx = (sxf / n - xm * fm) / vf if vf > 0 else 0.0
        vy = (syf / n - ym * fm) / vf if vf > 0 else 0.0
        cxx, cyy, cxy = sxx / n - xm * xm, syy / n - ym * ym, sxy / n - xm * ym
        evals, evecs = np.linalg.eigh(np.array([[cxx, cxy], [cxy, cyy]]))
        d = evecs[:, 1] if evals[1] > 1e-12 else np.array([1.0, 0.0])
        normal = np.array([-d[1], d[0]])
        theta = np.arctan2(normal[1], normal[0])
        if theta < 0:
            theta += np.pi
        if theta >= np.pi:
            theta -= np.pi
        rho = xm * np.cos(theta) + ym * np.sin(theta)
        out[i]["track_id"] = t.track_id
        out[i]["rho"], out[i]["theta"] = rho, theta
        out[i]["vx"], out[i]["vy"] = vx, vy
        out[i]["n_points"] = int(n)
        out[i]["score"] = meas / n
        out[i]["frame_start"], out[i]["frame_end"] = t.first_frame, t.last_frame
        f0 = out[i]["frame_start"]
        out[i]["x0"], out[i]["y0"] = xm + vx * (f0 - fm), ym + vy * (f0 - fm)
    return out
