"""Frames that repeat the frame before them exactly, and the time they leave out.

A video converted from one frame rate to another (a 25 frames/s sensor shown at 30) shows
every 5th or 6th frame twice. The repeat is no new observation: a target in it has not
moved, and a stage that takes the frames to be equally spaced in time sees the target stop
for a frame and then go on, its velocity broken at every repeat. The new frames are the
equally spaced ones. When the repeats are a conversion's (:func:`is_conversion`; a
recording's lone repeat is a frame like any other), ``irdetect track`` therefore runs on the
new frames alone (:class:`NewFrames`) and gives each repeat the points of the frame it
repeats (:meth:`FrameGroups.expand`), and ``irdetect process``'s per-frame path runs its
chains on the new frames' clock (``irdetect.pipeline.perframe.new_frame_clock``); a
velocity per new frame is one per input frame times the share of input frames that are
new (``FrameGroups.scale``).

Only exact repeats count (every pixel equal): the istd640 clips of ../shared/data/real
repeat their background every 6th frame nearly exactly (a mean absolute difference of
0.03-0.09 grey levels against 0.33-0.73), yet their target moves on in those frames as in
any other (docs/real.md, "Repeated frames").
"""

from __future__ import annotations

import numpy as np

from irdetect.io.sources import FrameView

__all__ = ["FrameGroups", "NewFrames", "frame_groups", "is_conversion", "repeated_frames"]

#: frames read first to decide whether a sequence repeats frames at all
PROBE = 64
#: the share of frames that repeat in a frame-rate conversion at least (it repeats 1 in 5
#: or 6; a recording's lone repeat is a frame like any other)
SHARE = 0.05


def is_conversion(n_repeats: int, n_frames: int) -> bool:
    """Whether ``n_repeats`` of ``n_frames`` frames repeating the frame before them are a
    frame-rate conversion's: ``SHARE`` of them and at least 2."""
    return n_repeats >= max(2.0, SHARE * n_frames)


class FrameGroups:
    """The new frames of a sequence, each with the repeats that follow it.

    New frame k (counted from 0) is input frame ``first[k]``, and input frames
    ``first[k] + 1 .. last[k]`` repeat it.

    Parameters
    ----------
    n_frames : int
        Input frames T.
    repeats : array_like of int
        The input frames (1 .. T-1) that repeat the frame before them exactly.

    Examples
    --------
    >>> g = FrameGroups(5, [2, 3])
    >>> g.n_new, g.scale, g.first([1, 2]).tolist(), g.last([1, 2]).tolist()
    (3, 0.6, [1, 4], [3, 4])
    """

    def __init__(self, n_frames: int, repeats=()):
        self.n_input = int(n_frames)
        new = np.ones(self.n_input, bool)
        new[np.asarray(repeats, np.int64)] = False
        if self.n_input:
            new[0] = True
        self._first = np.flatnonzero(new)
        self._last = np.r_[self._first[1:] - 1, self.n_input - 1][:len(self._first)]

    @property
    def n_new(self) -> int:
        """New frames."""
        return len(self._first)

    @property
    def scale(self) -> float:
        """New frames per input frame (1 without repeats): a velocity per new frame times
        this is one per input frame."""
        return self.n_new / self.n_input if self.n_input else 1.0

    def first(self, k) -> np.ndarray:
        """Input frame of new frame(s) ``k``."""
        return self._first[np.asarray(k, np.int64)]

    def last(self, k) -> np.ndarray:
        """Last input frame showing new frame(s) ``k`` (its last repeat, or itself)."""
        return self._last[np.asarray(k, np.int64)]

    def expand(self, rows: np.ndarray, velocity=("vx", "vy")) -> np.ndarray:
        """Rows of a table whose ``frame`` field counts new frames, as rows of input frames:
        each row once for its new frame and once for each repeat of it (in that order), its
        ``velocity`` fields scaled to px per input frame (``scale``), and a ``repeated``
        field (``irdetect.tables.CAMERA``'s) set on the repeats."""
        if not len(rows) or self.n_new == self.n_input:
            return rows
        k = rows["frame"].astype(np.int64)
        first, size = self._first[k], self._last[k] - self._first[k] + 1
        out = np.repeat(rows, size)
        later = np.arange(size.sum()) - np.repeat(np.cumsum(size) - size, size)
        out["frame"] = np.repeat(first, size) + later
        for name in velocity:
            out[name] *= self.scale
        if "repeated" in out.dtype.names:           # the /camera rows
            out["repeated"] |= later > 0
        return out


def frame_groups(frames, *, probe: int = PROBE, block: int = 64) -> FrameGroups:
    """The new frames of a sequence and the repeats after each.

    The first ``probe`` frames are compared with the frame before each; only when their
    repeats are a conversion's (``is_conversion``) is the whole sequence read once for its
    repeats (a second reading of the input), otherwise every frame counts as new.

    Parameters
    ----------
    frames : ndarray of shape (T, H, W) or FrameSource
        Anything with ``len()``, ``.shape`` and slicing.

    Returns
    -------
    FrameGroups
    """
    n = int(frames.shape[0])
    head = np.asarray(frames[0:min(n, probe)])
    found = repeated_frames(head)
    if not is_conversion(len(found), len(head)):
        return FrameGroups(n)
    last = head[-1]
    for a in range(len(head), n, block):
        raw = np.asarray(frames[a:a + block])
        found = np.r_[found, a + repeated_frames(raw, last)]
        last = raw[-1]
    return FrameGroups(n, found)


def repeated_frames(raw: np.ndarray, before: np.ndarray | None = None) -> np.ndarray:
    """Indices into ``raw`` (n, H, W) of its frames equal to the frame before them, bit for
    bit (``before``, (H, W), is the one before the first; None: the first is not
    compared). One frame compared at a time: no temporary of the block's size."""
    prev, found = before, []
    for i, frame in enumerate(raw):             # a loop over frames
        if prev is not None and np.array_equal(frame, prev):
            found.append(i)
        prev = frame
    return np.asarray(found, np.int64)


class NewFrames(FrameView):
    """A sequence seen without its repeated frames (:class:`FrameGroups`).

    Parameters
    ----------
    frames : ndarray of shape (T, H, W) or FrameSource
        Anything with ``len()``, ``.shape`` and slicing ``frames[a:b]`` -> (b - a, H, W).
    groups : FrameGroups
        Its new frames.
    """

    def __init__(self, frames, groups: FrameGroups):
        self.groups = groups
        super().__init__(frames, (groups.n_new,) + tuple(int(v) for v in frames.shape[1:]),
                         frames.dtype)

    def _read(self, start: int, stop: int) -> np.ndarray:
        if stop <= start:
            return np.zeros((0,) + self.shape[1:], self.dtype)
        first = int(self.groups.first(start))
        raw = self._raw(first, int(self.groups.first(stop - 1)) + 1)
        return raw[self.groups.first(np.arange(start, stop)) - first]
