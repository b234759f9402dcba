"""The sensor model of a scans file and every initiation parameter derived from it.

A scans file's measurements are described by their position error and the speeds the
targets may have; everything else (Hough cells, tiles, vote thresholds, gates) follows from
those, the scan period and the extent of the measurements (``derive_params``; the formulas
are in its Notes and in docs/initiation.md). Units are the file's: a file in km and the same
file in m give the same tracks, scaled.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from irdetect.errors import InputError
from irdetect.hough import MAX_CELLS

#: What to give when a file has no sensor model (one line, for ``InputError``).
NEED = ("no sensor model: give --sigma S (Cartesian, file units) or --sigma-range S "
        "--sigma-azimuth DEG (polar), and --speed MIN:MAX (file units per second), or the "
        "root attributes sigma / sigma_range / sigma_azimuth (rad) / speed_min / speed_max")

#: Upper bound of the derived grid (cells of all tiles); below hough.MAX_CELLS.
GRID_CELLS = min(MAX_CELLS, 2 * 10**7)


@dataclass(frozen=True)
class SensorModel:
    """Measurement error and target speeds of a scans file (the file's units).

    Attributes
    ----------
    sigma : float
        Cartesian position error per axis (0: none given).
    sigma_range, sigma_azimuth : float
        Polar errors of a radar at the origin: range (file units) and azimuth (rad).
    speed_min, speed_max : float
        Target speeds, file units per second (speed_max > 0).
    """

    sigma: float = 0.0
    sigma_range: float = 0.0
    sigma_azimuth: float = 0.0
    speed_min: float = 0.0
    speed_max: float = 0.0

    @property
    def polar(self) -> bool:
        return self.sigma_range > 0 and self.sigma_azimuth > 0

    def __post_init__(self):
        for name in ("sigma", "sigma_range", "sigma_azimuth", "speed_min", "speed_max"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {v!r}")
        if self.speed_max and self.speed_min > self.speed_max:
            raise ValueError(f"speed_min={self.speed_min} exceeds speed_max={self.speed_max}")


def sensor_model(attrs: dict | None = None, *, path=None, **given) -> SensorModel:
    """The sensor model from ``given`` values (CLI options; None = not given), else the
    scans file's root attributes ``attrs`` (``sigma``, ``sigma_range``, ``sigma_azimuth``
    in rad, ``speed_min``, ``speed_max``).

    Raises
    ------
    InputError
        Neither gives a position error (``sigma``, or ``sigma_range`` and
        ``sigma_azimuth``) and ``speed_max``: the one line ``NEED`` says what to give.
        A bad value (negative, min above max) names it.
    """
    attrs = attrs or {}
    values = {}
    for name in ("sigma", "sigma_range", "sigma_azimuth", "speed_min", "speed_max"):
        v = given.get(name)
        if v is None:
            v = attrs.get(name)
        try:
            values[name] = float(v) if v is not None else 0.0
        except (TypeError, ValueError):
            raise InputError(f"{name} must be a number, got {v!r}", path) from None
    try:
        s = SensorModel(**values)
    except ValueError as exc:
        raise InputError(str(exc), path) from None
    if not (s.sigma > 0 or s.polar) or not s.speed_max > 0:
        raise InputError(NEED, path)
    return s


def scan_period(scans) -> float:
    """Median time between consecutive scan numbers (s), from ``time`` of ``/scans``;
    1.0 for fewer than two scans."""
    u, first = np.unique(np.asarray(scans["scan"]), return_index=True)
    if u.size < 2:
        return 1.0
    t = np.asarray(scans["time"], float)[first]
    return float(np.median(np.diff(t) / np.diff(u)))


def derive_params(sensor: SensorModel, scans, *, window: int | None = None,
                  false_tracks: float = 0.05) -> dict:
    """Every initiation parameter of a scans file from its sensor model.

    Parameters
    ----------
    sensor : SensorModel
        Position error and target speeds (the file's units, per second).
    scans : structured ndarray
        ``tables.SCAN`` rows (scan, time in s, x, y; range, azimuth in rad or NaN).
    window : int, optional
        Scans per initiation window M (default: 10, or all scans when there are fewer).
    false_tracks : float
        Expected false tracks per window the per-track clutter test allows (0: no test,
        the global ``min_points`` instead).

    Returns
    -------
    dict
        Every key of ``irdetect.initiate.DEFAULTS`` (and ``window``), in the file's units.

    Notes
    -----
    With M scans per window, period T, largest target speed v_max and the position error
    s (Cartesian sigma; polar: max(sigma_range, r_med sigma_azimuth), r_med the median
    measured range):

    * ``rho_step`` = 2 s: a target's measurements (within 1 s of its line for 68 %, 2 s for
      95 %) fill one or two rho cells;
    * the longest track of a window is L = v_max (M - 1) T; ``n_theta`` = ceil(pi L /
      rho_step) (at least 16, at most 720): a theta cell of pi / n_theta turns a track of
      length L by at most L pi / (2 n_theta) <= rho_step / 2 across its cell;
    * ``tile`` = 2 (L + 2 gate s) (any track of the window lies wholly inside one tile,
      whose stride is tile / 2), or 0 (one accumulator) when that is at least the extent
      of the measurements; ``rho_step`` grows when the tiles' grid would exceed
      ``GRID_CELLS`` cells;
    * ``vote_fraction`` = max(0.6, 4 / M) (capped at 1): a candidate cell needs at least
      4 votes and 60 % of the window (zhang2010's 0.6 of 10, liang2015's 4 of 5);
    * ``min_hits`` = max(4, 0.6 M) / M with the per-track clutter test on
      (``false_tracks`` > 0, ``irdetect.initiate.clutter``: it decides which tracks
      clutter explains); with ``false_tracks`` = 0, n / M, n the points a track needs
      (``min_points``): the same max(4, 0.6 M), more when the clutter is dense enough
      that chains of n clutter points would pass the constant-velocity check;
    * ``false_tracks`` as given (default 0.05 expected false tracks per window);
    * ``v_min``, ``v_max`` = the speed range widened by ``gate`` sigma_v, the speed error
      of a least-squares fit over the window, sigma_v = s sqrt(12 / (M (M^2 - 1))) / T
      (a slow target under a large error would otherwise fail the speed gate; L above
      uses this v_max); ``gate`` 3 sigma, ``fit_confidence`` 0.99;
    * ``confirm_m`` / ``confirm_n``: M - 1 of M for M <= 5, else 3 of 4 (M/N logic);
    * fuzzy parallel Hough: ``q1`` 0.1 (a scan's point may lie 2.15 sigma_rho from the
      cell's line, exp(-2.15^2 / 2) = 0.1; the paper's 0.25, 1.67 sigma, dropped 14 % of
      the targets of random Cartesian scenes with 2-sigma cells), ``q2`` 0.3 with
      ``merge_peaks`` (docs/initiation.md: the paper's 0.65 loses the weakest peak),
      ``parallel_fraction`` 0.8;
    * ``sigma`` = s for Cartesian measurements; for polar ones ``sigma`` = sigma_range
      (the floor of every measurement's error), ``sigma_range``, ``sigma_azimuth`` as given
      (each measurement's error ellipse then comes from its own range).

    Every length above is proportional to s, v_max T and the extent, so scaling the
    file's units scales every derived length and leaves the counts as they are.
    """
    sc = np.asarray(scans)
    n_scans = int(np.unique(sc["scan"]).size) if sc.size else 0
    M = int(window) if window else max(2, min(10, n_scans))
    T = scan_period(sc) if sc.size else 1.0
    x, y = np.asarray(sc["x"], float), np.asarray(sc["y"], float)
    extent = float(max(np.ptp(x), np.ptp(y))) if x.size else 0.0
    r = np.asarray(sc["range"], float) if sc.size else np.zeros(0)
    polar = sensor.polar and r.size > 0 and bool(np.isfinite(r).all())
    if polar:
        s = max(sensor.sigma_range, float(np.median(r)) * sensor.sigma_azimuth, sensor.sigma)
    else:
        s = sensor.sigma if sensor.sigma > 0 else max(sensor.sigma_range, 0.0)
    if not s > 0:
        raise ValueError("the sensor model gives no position error")
    gate = 3.0
    # the speed gates of the CV check hold the fit's own speed error (a least-squares
    # velocity over M scans T apart has sigma_v = s sqrt(12 / (M (M^2 - 1))) / T)
    sv = s * math.sqrt(12.0 / (M * (M * M - 1))) / T
    v_lo, v_hi = max(0.0, sensor.speed_min - gate * sv), sensor.speed_max + gate * sv
    L = v_hi * (M - 1) * T
    rho_step = 2.0 * s
    tile = 2.0 * (L + 2 * gate * s)
    if not tile < extent:
        tile = 0.0
    n_theta = int(min(720, max(16, math.ceil(math.pi * L / rho_step))))
    rho_step = _fit_grid(rho_step, tile, n_theta, x, y)
    n_theta = int(min(720, max(16, math.ceil(math.pi * L / rho_step))))
    if false_tracks > 0:
        # the per-track clutter test decides (irdetect.initiate.clutter): the floor only
        # (a higher count from the density of every measurement, targets included, lost
        # targets of sparse scenes: polar random scenes, seeds 0-7, Hough + SC Pt 0.955
        # -> 0.932 with points_needed-style pruning)
        min_hits = min(M, max(4, math.ceil(0.6 * M - 1e-9))) / M
    else:
        min_hits = min_points(sc, M=M, period=T, speed_max=v_hi, s=s, gate=gate) / M
    confirm_n, confirm_m = (M, max(2, M - 1)) if M <= 5 else (4, 3)
    return dict(
        method="hough-sc", n_theta=n_theta, rho_step=rho_step, tile=tile,
        vote_fraction=min(1.0, max(0.6, 4.0 / M)), parallel_fraction=0.8, q1=0.1, q2=0.3,
        sigma=sensor.sigma_range if polar else s,
        sigma_range=sensor.sigma_range if polar else 0.0,
        sigma_azimuth=sensor.sigma_azimuth if polar else 0.0,
        radius_rho=3.0, radius_theta=4.0, squash=1.25, accept_ratio=0.5, reject_ratio=0.15,
        merge_peaks=True, nms_size=5, verify=True, gate=gate, v_min=v_lo,
        v_max=v_hi, min_hits=min_hits, confirm_m=confirm_m,
        confirm_n=confirm_n, fit_confidence=0.99, false_tracks=float(false_tracks), window=M)


def min_points(scans, *, M: int, period: float, speed_max: float, s: float,
               gate: float = 3.0, expected: float = 0.05) -> int:
    """Points a track needs in a window of M scans so that clutter rarely forms one.

    With N measurements per scan over the area A of their bounding box (density
    c = N / A), the expected number of chains of n clutter points that look like a
    constant-velocity track in one window is about

        E_n = N c pi (v_max T + gate s)^2 (c 2 pi (gate s)^2)^(n - 2) C(M, n)

    (every measurement starts a chain, a second point within reach of the speed, every
    further point inside the fit's gate; C(M, n) choices of the scans; the factor 2 for
    the fit's own error). The result is the smallest n >= max(4, 0.6 M) with
    E_n <= ``expected``, at most M - 1 for M >= 6 (a track may miss one scan or have one
    point outside its gate), else M.
    """
    sc = np.asarray(scans)
    lo = min(M, max(4, math.ceil(0.6 * M - 1e-9)))
    n_scans = int(np.unique(sc["scan"]).size) if sc.size else 0
    if n_scans < 2:
        return max(2, lo)
    area = float(np.ptp(sc["x"]) * np.ptp(sc["y"]))
    N = sc.size / n_scans
    if not area > 0:
        return max(2, lo)
    c = N / area
    pairs = N * c * math.pi * (speed_max * period + gate * s) ** 2
    p_gate = c * 2 * math.pi * (gate * s) ** 2
    top = M - 1 if M >= 6 else M
    for n in range(max(2, lo), top + 1):
        if pairs * p_gate ** (n - 2) * math.comb(M, n) <= expected:
            return n
    return max(2, lo, top)


def _fit_grid(rho_step, tile, n_theta, x, y):
    """``rho_step``, enlarged until the grid of all tiles holds at most GRID_CELLS cells
    (the same tiling as ``irdetect.initiate.base.Window``)."""
    if not x.size:
        return rho_step
    for _ in range(20):
        if tile > 0:
            stride = tile / 2
            nx = max(1, math.ceil(np.ptp(x) / stride))
            ny = max(1, math.ceil(np.ptp(y) / stride))
            groups, rmax = nx * ny, tile / math.sqrt(2) + rho_step
        else:
            groups, rmax = 1, float(np.hypot(x, y).max()) + rho_step
        if groups * math.ceil(2 * rmax / rho_step) * n_theta <= GRID_CELLS:
            break
        rho_step *= 1.5
    return rho_step


def explain_empty(params: dict, scans, sensor: SensorModel | None = None) -> str:
    """Why a run may have found no track: the derived cell size, tile, threshold and
    speeds next to the spread of the measurements (one line for the log)."""
    sc = np.asarray(scans)
    n_scans = int(np.unique(sc["scan"]).size) if sc.size else 0
    extent = float(max(np.ptp(sc["x"]), np.ptp(sc["y"]))) if sc.size else 0.0
    M = params.get("window") or n_scans
    need = max(2, math.ceil(params["min_hits"] * min(M, max(n_scans, 1)) - 1e-9))
    why = [f"no tracks from {sc.size} measurements in {n_scans} scans (extent {extent:.4g})"]
    if n_scans < 2:
        why.append("a track needs at least 2 scans")
    else:
        why.append(f"cells {params['rho_step']:.4g} x {params['n_theta']} theta, tile "
                   f"{params['tile']:.4g}, a track needs {need} of {M} scans within "
                   f"{params['gate']:g} sigma = {params['gate'] * params['sigma']:.4g} of a "
                   f"constant-velocity line at speed {params['v_min']:.4g}-"
                   f"{params['v_max'] or float('inf'):.4g} per s")
        if extent and params["sigma"] < 1e-4 * extent:
            why.append(f"sigma {params['sigma']:.3g} is under 1e-4 of the extent: are sigma "
                       "and the file in the same units?")
        if extent and params["rho_step"] > 0.2 * extent:
            why.append(f"the rho cell {params['rho_step']:.4g} is over a fifth of the extent: "
                       "is sigma too large?")
    return "; ".join(why)
