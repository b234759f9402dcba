"""The tracker's confirmation test: is a tentative track more likely a target than clutter?

A tentative track (``irdetect.track.tracker``) is confirmed only when

1. it **moves against the scene**: its least-squares constant-velocity fit moves by at
   least 3 sqrt(2) ``sigma`` px from its first to its last hit (as the per-frame path of
   ``irdetect process`` requires, ``irdetect.pipeline.perframe``). Structure that stays
   put in the scene (ground clutter the background leaves as residue) never does,
   whatever its SNR; the regions and tracks are in scene coordinates (image minus the
   camera's offset), so this holds for a panning camera too (the sensor's fixed pattern,
   which stays put in the image, does move against the scene with the camera: requiring
   motion in the image as well removed 14 of istd640-seq3-135's 26 false tracks but lost
   the DAUB targets the camera holds still, so it is not done);
   Its motion must also be **significant against its own scatter**: the F test of zero
   velocity of that fit, ``still_chance`` (the chance that a point which stays put, its
   centroid scattered as much as the track's hits scatter about their line, fits a line
   that moves this much) at most ``motion_p`` / ``window`` (the test is made at every
   frame of a tentative life, as test 2's). A centroid that wanders over a bright
   structure can drift the 3 sqrt(2) sigma of the first test (istd640-seq1-243's
   clutter-only crop: 4.6 px in 8 hits scattered 1.4 px about their line, chance 0.005),
   a target's hits lie on their line (the real folders' targets, a scratch measurement:
   chance < 1e-10 at confirmation). A track whose motion is significant and which
   passes test 2 when its tentative life of ``window`` frames is over, but not yet the
   displacement (a target slower than 3 sqrt(2) sigma per ``window`` frames) or test
   3's level, is not ended but tested on, with its hits, up to
   ``irdetect.track.tracker.SLOW_LIFE`` windows (``significant``): ended, it would start
   again from nothing, and a slow one would never move far enough (reversed easy1's
   target had moved 0.99 of the displacement at frame 30, with a still chance of
   1.7e-26);
2. clutter of the density measured around it would make at most ``false_tracks`` tracks
   per frame as good anywhere in the frame: the scans clutter test of
   ``irdetect.initiate.clutter`` (``chain_expectation``), E = H J min_j B(n_j; M, p(g_j))
   with M the frames since its birth, n_j its hits within ``gate`` x LEVELS[j] sigmas of
   its fit (sigma = ``sigma`` px), H the constant-velocity hypotheses of a frame of the
   sequence's size over M - 1 frames at speeds up to ``max_speed`` px/frame, and the
   clutter density the regions within ``radius`` px of its predictions that it did not
   take, per frame and px^2, at least ``floor`` (the white-noise peaks per frame the
   detector's level allows, over the frame's area) and at least the density of all the
   regions of the frames seen so far (``observe``): a 16-px disc that held no other
   region in 4 frames does not say the clutter is thin, and by the local count alone
   3-4 hits of clutter passed (the clutter-only crops of the real folders: 15 tracks by
   the local count, 9 with this floor, docs/tracking.md). A track is tested at every frame of
   its tentative life, and a new track may start at every frame, so E is compared with
   ``false_tracks`` / ``window`` (``window`` = the frames a tentative track is tested on):
   a rate per frame;
3. its **score**, the median local SNR (the regions' contrast) of its hits, reaches the
   score that clutter of this sequence which moves as far reaches ``false_tracks`` times
   per frame, at least the detector's CFAR level. The clutter sample is every tentative
   track of ``min_hits`` hits or more that ended unconfirmed and every one alive (the one
   tested among them: it may be clutter too), each with its score s and displacement m
   (test 1's units). Taking s and m of clutter as independent, clutter tracks as good in both come at the rate of those
   scoring s or more times the share F(m) of the sample that moves m or more: the level is
   ``irdetect.operating.tail_threshold`` of the scores at ``false_tracks`` / F(m), F the
   exponential tail of the sample's displacements above their median
   (``irdetect.operating.tail_share``).
   A track that passes tests 1 and 2 and moves faster than ``clutter_speed`` against the
   scene is no sample of the clutter (it is what ``irdetect process``'s per-frame path
   judges by its chain alone, ``irdetect.pipeline.perframe``): when it failed only this
   test, because the level was high, it was a target, and in it went, raising the level
   for the next (bench_unseen scene 4: 7 targets at 3-4 px/frame, scores 11-12, each
   ending unconfirmed after 30 frames and setting the level for the others, no track at
   all). Slower ones stay in it: on the real istd640-seq1-243 bright points that drift 0.2
   px/frame against the scene (parallax over city blocks) pass tests 1 and 2, and their
   scores are what keeps the next such point out. Nor is a track started from three
   regions in a line (``irdetect.track.tracker``, three-point starts, its ``three_point``):
   such starts are a selection of their own, often made of a target's hits with a
   clutter region, and in the sample their scores raised the level over slow targets
   (bench_unseen scene 39: MOTA 0.59 -> 0.39).
   Bright structure that stays put (m < 1) then no longer sets the level a clearly moving
   track must reach (istd640-seq3-237: static clutter scoring up to 49 put the level at
   106-150 over a target of 30 moving 8 units in 11 frames), while a track that moves no
   farther than the sequence's clutter meets the scores of that clutter at
   ``false_tracks`` per frame, as before. Nothing is confirmed in the first ``learn``
   frames, while that sample is too young to say how the sequence's clutter scores (a
   track's points from its first hit on are still released once it is confirmed).

Coordinates: x = column, y = row, px; time in frames.
"""

from __future__ import annotations

import math

import numpy as np

from irdetect.initiate.clutter import LEVELS, chain_expectation, hypotheses
from irdetect.operating import tail_share, tail_threshold

#: the gate (sigmas) of the clutter test and of the motion test (the scans' default)
GATE = 3.0


def still_chance(frame: np.ndarray, x: np.ndarray, y: np.ndarray) -> float:
    """The F test of zero velocity of a constant-velocity least-squares fit.

    With n hits, the fit's velocity v = (vx, vy) and S = sum (t - mean t)^2 over the
    hits' frames t, the residual variance per axis s^2 = sum (ex^2 + ey^2) / (2 (n - 2))
    and F = |v|^2 S / (2 s^2), which for a point that stays put (independent Gaussian
    scatter) follows F(2, 2 (n - 2)): the chance of an F this large is
    (1 + F / (n - 2))^-(n - 2). The fit is made twice: the second time without the
    hits more than 3 times the median distance from the first line (a noise peak a
    young track took in its wide gate fits a motion the point does not have).

    Parameters
    ----------
    frame, x, y : ndarray of shape (n,)
        The hits' frames and positions (x = column, y = row, px).

    Returns
    -------
    float
        The chance in [0, 1]; 1 with fewer than 3 hits or all in one frame, 0 for hits
        exactly on a moving line.
    """
    f, x, y = (np.asarray(a, np.float64)[None, :] for a in (frame, x, y))
    return float(_still_chances(f, x, y, np.ones(f.shape, bool))[0])


def _still_chances(f, x, y, w) -> np.ndarray:
    """``still_chance`` of N tracks at once: hits (N, K) padded, ``w`` marking the real
    ones; shape (N,)."""
    _, _, ex, ey = _lines(f, x, y, w)
    e = np.hypot(ex, ey)
    with np.errstate(all="ignore"):
        keep = w & (e <= 3.0 * _median(e, w)[:, None])
        vx, vy, ex, ey = _lines(f, x, y, keep)
        n = keep.sum(axis=1)
        t = np.where(keep, f - _mean(f, keep)[:, None], 0.0)
        S = (t * t).sum(axis=1)
        s2 = (ex * ex + ey * ey).sum(axis=1) / (2 * (n - 2))
        motion = (vx * vx + vy * vy) * S / 2
        chance = (1.0 + motion / s2 / (n - 2)) ** -(n - 2.0)
    chance = np.where(s2 <= 0, np.where(motion > 0, 0.0, 1.0), chance)
    few = (w.sum(axis=1) < 3) | (_span(f, w) == 0) | (n < 3) | (_span(f, keep) == 0)
    return np.where(few, 1.0, chance)


def _median(a, w) -> np.ndarray:
    """Median over axis 1 of ``a`` (N, K) where ``w`` (``np.median`` of each row's real
    values: the middle one, or the mean of the middle two); NaN for a row without any."""
    n = w.sum(axis=1)
    s = np.sort(np.where(w, a, np.inf), axis=1)
    rows = np.arange(len(a))
    lo = s[rows, np.maximum(n - 1, 0) // 2]
    hi = s[rows, np.minimum(n // 2, a.shape[1] - 1)]
    return np.where(n > 0, (lo + hi) / 2, np.nan)


def _mean(a, w) -> np.ndarray:
    """Mean over axis 1 of ``a`` (N, K) where ``w``; 0 for a row without any."""
    return np.where(w, a, 0.0).sum(axis=1) / np.maximum(w.sum(axis=1), 1)


def _span(f, w) -> np.ndarray:
    """max - min over axis 1 of ``f`` (N, K) where ``w``; 0 for a row without any."""
    if not f.size:
        return np.zeros(len(f))
    hi = np.where(w, f, -np.inf).max(axis=1)
    lo = np.where(w, f, np.inf).min(axis=1)
    return np.where(w.any(axis=1), hi - lo, 0.0)


def _lines(f, x, y, w):
    """The least-squares constant-velocity fits x(t), y(t) of N tracks' hits at frames
    ``f`` (each (N, K), padded; ``w`` marks the real hits): velocities vx, vy of shape
    (N,), px/frame (0 when all of a track's hits share one frame), and the residuals ex,
    ey of shape (N, K), px (0 where padded)."""
    t = np.where(w, f - _mean(f, w)[:, None], 0.0)
    vt = (t * t).sum(axis=1)

    def slope(v):
        d = np.where(w, v - _mean(v, w)[:, None], 0.0)
        return np.where(vt > 0, (t * d).sum(axis=1) / np.where(vt > 0, vt, 1.0), 0.0)

    vx, vy = slope(x), slope(y)
    ex = np.where(w, x - (_mean(x, w)[:, None] + vx[:, None] * t), 0.0)
    ey = np.where(w, y - (_mean(y, w)[:, None] + vy[:, None] * t), 0.0)
    return vx, vy, ex, ey


def _padded(meas_lists) -> tuple[np.ndarray, np.ndarray]:
    """N tracks' hit rows (each a list or array of rows of equal length) as one array of
    shape (N, K, columns), K the most hits, and the mask (N, K) of the real rows."""
    counts = np.array([len(m) for m in meas_lists])
    rows = np.array([r for m in meas_lists for r in m], np.float64)
    w = np.arange(max(int(counts.max()), 1))[None, :] < counts[:, None]
    out = np.zeros(w.shape + rows.shape[1:])
    out[w] = rows
    return out, w


class ClutterTest:
    """The confirmation test of tentative tracks (module notes).

    Parameters
    ----------
    shape : (int, int)
        Frame (H, W).
    false_tracks : float
        Clutter tracks per frame allowed (> 0).
    sigma : float
        Position error of a region, px (> 0).
    max_speed : float
        Largest speed against the scene, px/frame (> 0).
    radius : float
        Regions within this many px of a track's predictions count as its local clutter.
    floor : float
        Lowest clutter density, regions per frame per px^2.
    window : int
        Frames a tentative track is tested on (the tracker's ``confirm_window``).
    score_floor : float
        The lowest score level (test 3): the detector's CFAR level.
    misses : int
        A tentative track ends after more than this many consecutive misses.
    learn : int
        Frames before the first confirmation (test 3).
    motion_p : float
        The chance, in (0, 1], that a point which stays put passes the significance test
        of test 1 in its tentative life: each frame's ``still_chance`` must be at most
        ``motion_p`` / ``window``; 1: no significance test.
    clutter_speed : float
        px/frame against the scene: a tentative track that passes tests 1 and 2 and moves
        this fast or faster is no sample of the clutter (test 3; >= 0; inf: every track,
        the design before).
    """

    def __init__(self, shape, *, false_tracks: float, sigma: float = 1.0,
                 max_speed: float = 16.0, radius: float = 16.0, floor: float = 0.0,
                 window: int = 30, score_floor: float = 0.0, misses: int = 3,
                 learn: int = 12, motion_p: float = 0.001, clutter_speed: float = 1.5):
        for name, value in (("false_tracks", false_tracks), ("sigma", sigma),
                            ("max_speed", max_speed), ("radius", radius)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value!r}")
        if not 0 < motion_p <= 1:
            raise ValueError(f"motion_p must lie in (0, 1], got {motion_p!r}")
        if not clutter_speed >= 0:
            raise ValueError(f"clutter_speed must be a number >= 0, got {clutter_speed!r}")
        self.clutter_speed = float(clutter_speed)
        self.still_level = 1.0 if motion_p == 1 else float(motion_p) / max(int(window), 1)
        self.area = float(shape[0]) * float(shape[1])
        self.rate = float(false_tracks) / max(int(window), 1)
        self.sigma, self.max_speed = float(sigma), float(max_speed)
        self.radius, self.floor = float(radius), float(floor)
        self.false_tracks = float(false_tracks)
        self.score_floor = float(score_floor)
        # (score, displacement) of the tentative tracks that ended unconfirmed
        self.ended_sample = np.zeros((0, 2))
        self.misses = int(misses)
        self.learn = int(learn)
        # regions and frames seen: the frame's clutter density (at least the local one)
        self.regions_seen, self.frames_seen = 0, 0

    def observe(self, n_regions: int) -> None:
        """Count a frame's regions (the sequence's clutter density, test 2)."""
        self.regions_seen += int(n_regions)
        self.frames_seen += 1

    def expectation(self, meas: np.ndarray, age: int, clutter: int) -> tuple[float, float]:
        """E and the fit's displacement of one track.

        Parameters
        ----------
        meas : ndarray of shape (n, 3) or (n, more)
            The track's hits: frame, x, y (scene coordinates, px); further columns are
            ignored.
        age : int
            Frames since its birth, inclusive (M).
        clutter : int
            Regions counted near its predictions over those frames.

        Returns
        -------
        E : float
            Expected clutter tracks as good (module notes).
        moved : float
            Displacement of the least-squares constant-velocity fit against the scene from
            the first to the last hit, in units of 3 sqrt(2) sigma (>= 1 passes test 1).
        """
        hits, w = _padded([np.asarray(meas, np.float64)])
        E, moved, _ = self._expectations(hits, w, np.array([age]), np.array([clutter]))
        return float(E[0]), float(moved[0])

    def _expectations(self, hits, w, age, clutter):
        """``expectation`` of N tracks at once: hits (N, K, columns) padded, ``w`` (N, K)
        marking the real ones, ``age`` and ``clutter`` of shape (N,); E, moved and the
        fit's speed (px/frame), each of shape (N,)."""
        f, x, y = hits[..., 0], hits[..., 1], hits[..., 2]
        vx, vy, ex, ey = _lines(f, x, y, w)
        e = np.where(w, np.hypot(ex, ey) / self.sigma, np.inf)
        span = _span(f, w)
        unit = GATE * math.sqrt(2.0) * self.sigma
        speed = np.hypot(vx, vy)
        moved = speed * span / unit
        M = np.maximum(np.asarray(age, np.int64), w.sum(axis=1))
        counted = (e[:, :, None] <= GATE * np.asarray(LEVELS)[None, None, :]).sum(axis=1)
        disc = math.pi * self.radius ** 2
        density = np.maximum.reduce([
            np.asarray(clutter) / (np.maximum(M, 1) * disc), np.full(len(M), self.floor),
            np.full(len(M), self.regions_seen / (max(self.frames_seen, 1) * self.area))])
        s = np.full(len(M), self.sigma)
        H = hypotheses(self.area, (M - 1).astype(np.float64), self.max_speed, GATE, s, s)
        E = chain_expectation(counted, M[:, None], density[:, None], s, s, H, GATE)
        return E, moved, np.where(span > 0, speed, 0.0)

    def measure(self, track, frame: int) -> None:
        """Set a tentative track's ``E``, ``moved``, ``still`` (its ``still_chance``),
        ``speed`` (its fit's, px/frame against the scene) and ``score`` (the median
        contrast of its hits: the peaks' local SNR) at ``frame``
        (``irdetect.track.tracker.Track``: its ``meas``, ``born`` and ``clutter``)."""
        self.measure_all([track], frame)

    def measure_all(self, tracks, frame: int) -> None:
        """``measure`` every track of ``tracks`` (a list) at ``frame``, in one pass."""
        if not tracks:
            return
        hits, w = _padded([t.meas for t in tracks])
        age = np.array([frame - t.born + 1 for t in tracks])
        clutter = np.array([t.clutter for t in tracks])
        E, moved, speed = self._expectations(hits, w, age, clutter)
        still = _still_chances(hits[..., 0], hits[..., 1], hits[..., 2], w)
        score = _median(hits[..., 5], w)
        one = w.sum(axis=1) < 2
        for i, t in enumerate(tracks):   # the results back on the track objects
            t.E, t.moved, t.still = ((math.inf, 0.0, 1.0) if one[i] else
                                     (float(E[i]), float(moved[i]), float(still[i])))
            t.speed = 0.0 if one[i] else float(speed[i])
            t.score = float(score[i])

    def sample(self, tracks, n_frames: int, min_hits: int) -> np.ndarray | None:
        """The clutter sample of test 3 at this frame (module notes).

        Parameters
        ----------
        tracks : list of irdetect.track.tracker.Track
            The live tracks (their ``score`` and ``moved`` measured).
        n_frames : int
            Frames seen so far.
        min_hits : int
            The hits a tentative track needs to count.

        Returns
        -------
        ndarray of shape (N, 2) or None
            Score and displacement (test 1's units) of the tracks that ended unconfirmed
            and of the live tentative ones; None before ``learn`` frames
            (too early to know this sequence's clutter).
        """
        if n_frames < self.learn:
            return None
        live = [(t.score, t.moved) for t in tracks if not t.confirmed
                and len(t.meas) >= min_hits and self.clutter_like(t)]
        return np.concatenate([self.ended_sample, np.reshape(live, (-1, 2))])

    def level(self, sample: np.ndarray | None, moved: float, n_frames: int) -> float:
        """The score a track that moved ``moved`` (test 1's units) must reach after
        ``n_frames`` frames: the score the clutter of ``sample`` (``ClutterTest.sample``)
        that moves as far reaches ``false_tracks`` times per frame, floored at the
        detector's level; inf with no sample yet."""
        if sample is None:
            return math.inf
        if not len(sample):
            return self.score_floor
        share = tail_share(sample[:, 1], moved)
        return tail_threshold(sample[:, 0], n_frames, self.false_tracks / share,
                              self.score_floor)

    def clutter_like(self, track) -> bool:
        """Whether a measured tentative track can be a sample of the clutter: not when it
        passes tests 1 and 2 and moves ``clutter_speed`` or faster, nor when it was started
        from three regions in a line (its ``three_point``; module notes)."""
        if getattr(track, "three_point", False):
            return False
        return not (self._moves_unlike_clutter(track)
                    and track.speed >= self.clutter_speed)

    def _moves_unlike_clutter(self, track) -> bool:
        """Tests 1 and 2 (module notes) of a measured tentative track."""
        return track.moved >= 1.0 and self.significant(track)

    def significant(self, track) -> bool:
        """Whether a measured tentative track's chain passes test 2 and its motion is
        significant against its own scatter (test 1 without the displacement). A track
        that is so when its tentative life is over, but lacks the displacement or test
        3's level, is tested on (module notes)."""
        return track.still <= self.still_level and track.E <= self.rate

    def ended(self, track, min_hits: int) -> None:
        """A tentative track that ends unconfirmed joins the clutter sample (score and
        displacement) when it is like clutter (``clutter_like``)."""
        if len(track.meas) >= min_hits and self.clutter_like(track):
            row = [[track.score, getattr(track, "moved", 0.0)]]
            self.ended_sample = np.concatenate([self.ended_sample, row])

    def passes(self, track, sample: np.ndarray | None, n_frames: int) -> bool:
        """Whether a measured tentative track passes the three tests after ``n_frames``
        frames (``sample``: that frame's ``ClutterTest.sample``)."""
        return (self._moves_unlike_clutter(track)
                and track.score >= self.level(sample, track.moved, n_frames))

