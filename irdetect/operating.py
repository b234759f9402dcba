"""The operating point: a score threshold set by a stated false-alarm rate, measured on the
sequence itself.

A detector's clutter does not follow the white-noise tail its first threshold assumes
(real ground, cloud edges and water glint have far heavier tails). Where the run holds a
sample of scores known to come from clutter (for the per-frame path: the tracks that do not
move against the scene, ``irdetect.pipeline.perframe``), the tail of that sample says how
often clutter reaches a score in this sequence, and the threshold is the score clutter
reaches ``rate`` times per frame.

The tail is modelled as exponential above the sample's median u (the peaks-over-threshold
model of extreme-value statistics, with the mean excess as its scale):

    N(s) = n_u exp(-(s - u) / lambda),   lambda = mean(s_i - u | s_i > u),

N(s) the clutter items per sequence at or above s, n_u those above u. The threshold is the
s at which N(s) / T = rate, T the frames of the sequence.
"""

from __future__ import annotations

import math

import numpy as np

#: fewest clutter scores above the sample's median a tail is fitted to; below it the
#: floor alone applies (a scale from 2 or 3 excesses is no estimate: 2 strong chains among
#: 11 put a simulated target of SNR 8 under the threshold)
MIN_SAMPLE = 8


def tail_threshold(clutter, n_frames: int, rate: float, floor: float) -> float:
    """The score clutter of this sequence reaches ``rate`` times per frame.

    Parameters
    ----------
    clutter : array_like of shape (N,)
        Scores of items known to be clutter (higher = more target-like).
    n_frames : int
        Frames of the sequence (T >= 1).
    rate : float
        Clutter items per frame allowed at or above the threshold (> 0).
    floor : float
        The lowest threshold returned (the white-noise level).

    Returns
    -------
    float
        max(floor, u + lambda log(n_u / (rate T))) (module notes); ``floor`` when fewer
        than ``MIN_SAMPLE`` scores lie above the median or the items per frame are within
        ``rate`` already.
    """
    if not (math.isfinite(rate) and rate > 0):
        raise ValueError(f"rate must be a positive number, got {rate!r}")
    s = np.asarray(clutter, np.float64).ravel()
    s = s[np.isfinite(s)]
    if s.size <= rate * n_frames:
        return float(floor)
    u = float(np.median(s)) if s.size else 0.0
    excess = s[s > u] - u
    if excess.size < MIN_SAMPLE:
        return float(floor)
    scale = float(excess.mean())
    return max(float(floor), u + scale * math.log(excess.size / (rate * n_frames)))
