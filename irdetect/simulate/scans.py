"""Radar-style measurement scans with ground truth (Zhang et al. 2010, Liang et al. 2015).

Model (docs/initiation.md): targets move at constant velocity, X(k+1) = F X(k) with
state [x, vx, y, vy] and scan period T; each target is detected in every scan with
probability ``detection_probability`` and measured

* Cartesian (``polar = false``): z = (x, y) + N(0, sigma^2 I), clutter uniform over
  ``region``, Poisson count of mean ``clutter_density`` (per km^2) x area;
* polar (``polar = true``): a radar at the origin measures range r + N(0, sigma_range^2)
  and azimuth beta + N(0, sigma_azimuth^2) (degrees in the preset); clutter uniform in
  area over the sector r <= max_range, beta in ``azimuth_span``, Poisson count of mean
  ``clutter_mean``; measurements are converted to x = r cos(beta), y = r sin(beta) and
  range and azimuth (radians) kept. Targets beyond ``max_range`` are not detected.

Coordinates in metres, time in seconds, scans counted from 0.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from irdetect import tables
from irdetect.config import from_dict
from irdetect.errors import InputError
from irdetect.simulate.presets import read_preset
SCAN_SCENARIOS = ("zhang2010", "liang2015")


@dataclass(frozen=True)
class ScanScenario:
    """Parameters of a simulated scans file (a ``kind = "scans"`` preset)."""

    n_scans: int = 10
    period: float = 1.0
    region: tuple = (0.0, 120000.0, 0.0, 120000.0)
    sigma: float = 100.0
    clutter_density: float = 0.03
    clutter_mean: float = 0.0
    polar: bool = False
    sigma_range: float = 0.0
    sigma_azimuth: float = 0.0
    max_range: float = 0.0
    azimuth_span: tuple = (0.0, 90.0)
    detection_probability: float = 1.0
    targets: tuple = ()
    speed_min: float = 0.0          # the targets' speed range the sensor model states
    speed_max: float = 0.0          # (units per s); 0: 0.5 x / 1.5 x the targets' speeds


def load_scan_scenario(name: str | os.PathLike = "zhang2010", **overrides):
    """Read ``data/presets/<name>.toml`` (or a TOML path) with overrides.

    Returns
    -------
    scenario : ScanScenario
    initiate : dict
        The preset's recommended initiation parameters (its ``[initiate]`` table).

    Raises
    ------
    InputError
        Unknown preset, not a scans preset, unknown key, bad value.
    """
    data, path = read_preset(name, "scans")
    initiate = data.pop("initiate", {})
    _validate(from_dict(ScanScenario, data, where="scenario", path=path), path)
    given = {k: v for k, v in overrides.items() if v is not None}
    s = from_dict(ScanScenario, {**data, **given}, where="scenario", path=path)
    if given:
        _validate(s, None)      # a bad value comes from the options, not the preset
    return s, initiate


#: the most clutter points a simulation draws (they are held in memory)
MAX_CLUTTER = 10_000_000


def _validate(s: ScanScenario, path=None):
    if s.n_scans < 1:
        raise InputError(f"n_scans must be >= 1, got {s.n_scans}", path, keys=("n_scans",))
    if not s.period > 0:
        raise InputError(f"period must be > 0, got {s.period}", path)
    for name in ("clutter_density", "clutter_mean"):
        if not getattr(s, name) >= 0:                            # NaN fails too
            raise InputError(f"{name} must be a number >= 0, got {getattr(s, name)}", path,
                             keys=(name,))
    if not 0 <= s.detection_probability <= 1:
        raise InputError(f"detection_probability must lie in [0, 1], got "
                         f"{s.detection_probability}", path)
    if s.polar and not s.max_range > 0:
        raise InputError("a polar scenario needs max_range > 0", path)
    if len(s.region) != 4 or not (s.region[1] > s.region[0] and s.region[3] > s.region[2]):
        raise InputError(f"region must be [x_min, x_max, y_min, y_max], got {s.region}", path)
    x0, x1, y0, y1 = s.region
    mean = (s.clutter_mean if s.clutter_mean > 0 or s.polar
            else s.clutter_density * (x1 - x0) * (y1 - y0) / 1e6)
    if mean * s.n_scans > MAX_CLUTTER:
        raise InputError(f"{mean * s.n_scans:.3g} clutter points expected over the scans, at "
                         f"most {MAX_CLUTTER:,} (lower the clutter density or mean)", path,
                         keys=("clutter_density", "clutter_mean", "n_scans"))
    for row in s.targets:
        if len(row) != 4:
            raise InputError(f"every target is [x, vx, y, vy], got {row}", path)
    if s.speed_min < 0 or s.speed_max < 0 or (s.speed_max and s.speed_min > s.speed_max):
        raise InputError(f"need 0 <= speed_min <= speed_max, got {s.speed_min}, "
                         f"{s.speed_max}", path)


def simulate_scans(scenario: str | ScanScenario = "zhang2010", *,
                   rng: np.random.Generator | int | None = None, **overrides):
    """Simulate measurement scans of CV targets in Poisson clutter.

    Parameters
    ----------
    scenario : str or ScanScenario
        Preset name (``zhang2010``, ``liang2015``), TOML path or a scenario.
    rng : numpy.random.Generator, int or None
        Random source (seed).
    **overrides
        Scenario fields to replace (e.g. ``clutter_density=0.1``, ``n_scans=6``).

    Returns
    -------
    scans : structured ndarray
        ``tables.SCAN`` rows sorted by scan (x, y in m; range, azimuth NaN unless polar).
    truth : structured ndarray
        ``tables.SCAN_TRUTH`` rows: true position of every target at every scan.
    attrs : dict
        Root attributes describing the sensor (scenario, period, sigma, ...).

    Examples
    --------
    >>> scans, truth, attrs = simulate_scans("zhang2010", rng=0, n_scans=6)
    >>> sorted(set(truth["target"]))
    [0, 1, 2]
    """
    if isinstance(scenario, ScanScenario):
        s = ScanScenario(**{**scenario.__dict__, **overrides})
        _validate(s)
        name = "custom"
    else:
        s, _ = load_scan_scenario(scenario, **overrides)
        name = Path(str(scenario)).stem
    rng = np.random.default_rng(rng)
    states = np.asarray(s.targets, float).reshape(-1, 4)
    k = np.arange(s.n_scans)
    times = k * s.period
    tx = states[:, 0][None, :] + states[:, 1][None, :] * times[:, None]     # (K, J)
    ty = states[:, 2][None, :] + states[:, 3][None, :] * times[:, None]
    J = states.shape[0]
    truth = tables.from_columns(tables.SCAN_TRUTH, scan=np.repeat(k, J),
                                target=np.tile(np.arange(J), s.n_scans),
                                x=tx.ravel(), y=ty.ravel())
    detected = rng.random(tx.shape) < s.detection_probability
    az_sigma = math.radians(s.sigma_azimuth)
    if s.polar:
        r_true, b_true = np.hypot(tx, ty), np.arctan2(ty, tx)
        r = r_true + rng.normal(0, s.sigma_range, tx.shape)
        b = b_true + rng.normal(0, az_sigma, tx.shape)
        detected &= r_true <= s.max_range
        r = np.abs(r)               # a negative measured range is the same point reflected
        a0, a1 = (math.radians(a) for a in s.azimuth_span)
        n_cl = rng.poisson(s.clutter_mean, s.n_scans)
        total = int(n_cl.sum())
        cr = s.max_range * np.sqrt(rng.random(total))
        cb = rng.uniform(a0, a1, total)
        rng_all = np.r_[r[detected], cr]
        az_all = np.r_[b[detected], cb]
        mx, my = rng_all * np.cos(az_all), rng_all * np.sin(az_all)
    else:
        mx_t = tx + rng.normal(0, s.sigma, tx.shape)
        my_t = ty + rng.normal(0, s.sigma, tx.shape)
        x0, x1, y0, y1 = s.region
        area_km2 = (x1 - x0) * (y1 - y0) / 1e6
        mean = s.clutter_mean if s.clutter_mean > 0 else s.clutter_density * area_km2
        n_cl = rng.poisson(mean, s.n_scans)
        total = int(n_cl.sum())
        mx = np.r_[mx_t[detected], rng.uniform(x0, x1, total)]
        my = np.r_[my_t[detected], rng.uniform(y0, y1, total)]
        rng_all = np.full(mx.size, np.nan)
        az_all = np.full(mx.size, np.nan)
    scan = np.r_[np.broadcast_to(k[:, None], tx.shape)[detected], np.repeat(k, n_cl)]
    order = np.lexsort((rng.random(scan.size), scan))          # clutter and targets mixed
    scans = tables.from_columns(tables.SCAN, scan=scan[order], time=times[scan[order]],
                                x=mx[order], y=my[order], range=rng_all[order],
                                azimuth=az_all[order])
    attrs = {"scenario": name, "period": s.period, "n_scans": s.n_scans,
             "sigma": s.sigma if not s.polar else max(s.sigma_range, 0.0),
             "polar": bool(s.polar)}
    if s.polar:
        attrs.update(sigma_range=s.sigma_range, sigma_azimuth=az_sigma, max_range=s.max_range)
    attrs.update(zip(("speed_min", "speed_max"), speed_range(s)))
    return scans, truth, attrs


def speed_range(s: ScanScenario) -> tuple[float, float]:
    """(speed_min, speed_max) of the sensor model: the scenario's, else 0.5 x the slowest
    and 1.5 x the fastest target's speed (units per s)."""
    if s.speed_max > 0:
        return float(s.speed_min), float(s.speed_max)
    v = np.hypot(*np.asarray(s.targets, float).reshape(-1, 4)[:, [1, 3]].T)
    return (0.5 * float(v.min()), 1.5 * float(v.max())) if v.size else (0.0, 0.0)


def random_scenario(rng: np.random.Generator | int | None = None, *, polar: bool = False,
                    n_scans: int = 10, clutter: str = "region") -> ScanScenario:
    """A random scans scene of any scale (the benchmark of issue 17).

    Region side E log-uniform in [10, 500] units (the file's units: km, m, anything);
    position error sigma uniform in [0.1, 2] % of E (polar: sigma_range so, sigma_azimuth
    = sigma_range / (E / 2) x U(0.5, 2), a cross-range error comparable to the range error
    at mid-range); 2-10 CV targets, period T uniform in [1, 5] s, speeds uniform in
    [speed_min, speed_max] with speed_max T uniform in [0.3, 3] % of E (zhang2010 0.3 %,
    liang2015 2.5 %) and speed_min = speed_max / 4, started so they stay in the region
    (polar: mid-window at 30-90 % of the range, azimuth 10-80 degrees); clutter density lambda uniform in [0, 0.1] per scaled unit^2,
    the region being 120 scaled units on a side as zhang2010's 120 km: a Poisson count of
    mean lambda x 120^2 x (area / E^2) per scan, uniform over the region (0 to 1,440 per
    scan over the square, as zhang2010 at lambda 0 to 0.1). ``clutter="sigma"`` scales
    the clutter to the sensor instead: lambda uniform in [0, 0.001] per sigma^2 per scan
    (zhang2010's lambda 0 to 0.1 per km^2 at sigma = 100 m), a mean count of
    lambda x area / sigma^2.

    Returns
    -------
    ScanScenario
        With ``speed_min``, ``speed_max`` set (the sensor model's speed range).
    """
    rng = np.random.default_rng(rng)
    E = float(np.exp(rng.uniform(np.log(10.0), np.log(500.0))))
    sigma = float(rng.uniform(0.001, 0.02)) * E
    T = float(rng.uniform(1.0, 5.0))
    vmax = float(rng.uniform(0.003, 0.03)) * E / T
    vmin = vmax / 4
    lam = float(rng.uniform(0.0, 0.1))
    if clutter not in ("region", "sigma"):
        raise ValueError(f"clutter must be 'region' or 'sigma', got {clutter!r}")
    # mean clutter count per scan over the square E x E
    count = lam * 120**2 if clutter == "region" else lam / 100 * E * E / sigma**2
    J = int(rng.integers(2, 11))
    speed = rng.uniform(vmin, vmax, J)
    heading = rng.uniform(0, 2 * np.pi, J)
    vx, vy = speed * np.cos(heading), speed * np.sin(heading)
    dur = (n_scans - 1) * T
    if polar:
        r0 = rng.uniform(0.3, 0.9, J) * E
        b0 = np.radians(rng.uniform(10, 80, J))
        mid_x, mid_y = r0 * np.cos(b0), r0 * np.sin(b0)
        x0, y0 = mid_x - vx * dur / 2, mid_y - vy * dur / 2
        sr = sigma
        sa = math.degrees(sr / (E / 2) * float(rng.uniform(0.5, 2.0)))
        return ScanScenario(n_scans=n_scans, period=T, region=(0.0, E, 0.0, E), polar=True,
                            sigma=sr, sigma_range=sr, sigma_azimuth=sa, max_range=E,
                            azimuth_span=(0.0, 90.0), clutter_mean=count * np.pi / 4,
                            targets=tuple(zip(x0, vx, y0, vy)), speed_min=vmin,
                            speed_max=vmax)
    lo, hi = 0.05 * E + np.abs(vx) * dur, 0.95 * E - np.abs(vx) * dur
    x0 = np.where(vx > 0, rng.uniform(0.05 * E, np.maximum(0.05 * E, hi)),
                  rng.uniform(np.minimum(lo, 0.95 * E), 0.95 * E))
    lo, hi = 0.05 * E + np.abs(vy) * dur, 0.95 * E - np.abs(vy) * dur
    y0 = np.where(vy > 0, rng.uniform(0.05 * E, np.maximum(0.05 * E, hi)),
                  rng.uniform(np.minimum(lo, 0.95 * E), 0.95 * E))
    return ScanScenario(n_scans=n_scans, period=T, region=(0.0, E, 0.0, E), sigma=sigma,
                        clutter_mean=count,
                        clutter_density=0.0, targets=tuple(zip(x0, vx, y0, vy)),
                        speed_min=vmin, speed_max=vmax)
