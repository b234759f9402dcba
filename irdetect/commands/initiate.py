"""Initiate tracks on radar-style measurement scans (/scans) in a sliding window of M scans.

Methods: hough-sc (Hough + subtractive clustering, Zhang et al. 2010), hough (plain
threshold), nms (greedy non-maximum suppression), opencv (cv2.HoughLinesPointSet),
parallel-hough, fuzzy-parallel-hough (Liang et al. 2015), mn-logic (M-of-N logic).

The sensor model is the interface: the measurement error (--sigma, or --sigma-range and
--sigma-azimuth for a radar at the origin) and the targets' speeds (--speed MIN:MAX, the
file's units per second), else the scans file's root attributes sigma, sigma_range,
sigma_azimuth (rad), speed_min, speed_max, else the sigma / sigma_range / sigma_azimuth /
v_min / v_max of --config's [initiate] table or of the preset the file names. Every grid
parameter (rho and theta cells, tiles, thresholds, gates) is derived from it, the scan
period and the extent of the measurements (irdetect.initiate.sensor.derive_params);
--config's [initiate] table, then the options, override any of them. A file of a named
scenario preset (zhang2010, liang2015) is run with the preset's tuned [initiate] table
instead of the derivation. Each track must pass the per-track clutter test: clutter of the
density measured in the window would give at most --false-tracks (default 0.05) chains as
good per window (irdetect.initiate.clutter); past the separable limit one warning says so.
Units are the file's. Writes /tracks (docs/initiation.md, docs/format.md).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math

import numpy as np

from irdetect.config import InitiateConfig, from_dict, read_toml
from irdetect.errors import InputError
from irdetect.initiate import DEFAULTS, METHODS, initiate_scans, scan_windows

log = logging.getLogger(__name__)


def add_arguments(p):
    p.add_argument("input", help="scans file (HDF5 with /scans: scan, time, x, y)")
    p.add_argument("-o", "--output", required=True, help="results file to write")
    p.add_argument("--sigma", type=float, help="Cartesian measurement error per axis, in the "
                   "file's units (default: the file's sigma attribute)")
    p.add_argument("--sigma-range", type=float,
                   help="polar: range error, in the file's units (default: attribute)")
    p.add_argument("--sigma-azimuth", type=float,
                   help="polar: azimuth error in degrees (default: the file's sigma_azimuth "
                   "attribute, in rad)")
    p.add_argument("--speed", metavar="MIN:MAX",
                   help="target speeds, the file's units per second (default: the file's "
                   "speed_min / speed_max attributes)")
    p.add_argument("--false-tracks", type=float, metavar="RATE",
                   help="expected false tracks per window the per-track clutter test allows "
                   "(default 0.05, or the config's initiate.false_tracks; 0 turns the test "
                   "off; a named preset's table runs without it)")
    p.add_argument("--method", choices=METHODS, help="initiation method (default: hough-sc "
                   "or the scenario preset's)")
    p.add_argument("--window", type=int, default=None,
                   help="sliding window length M in scans (default: the config's "
                   "initiate.window, else 10; all scans when there are fewer)")
    p.add_argument("--step", type=int, default=None, help="scans between windows (default M)")
    p.add_argument("--config", help="TOML file with an [initiate] table: overrides any "
                   "derived parameter")
    p.add_argument("--merge-peaks", action="store_true",
                   help="merge the cells of a peak by subtractive clustering (parallel methods)")
    p.add_argument("--no-verify", action="store_true",
                   help="paper form: every selected cell is a track (no constant-velocity check)")
    p.add_argument("--force", action="store_true", help="overwrite an existing output")


def _speed(text):
    """(min, max) of --speed MIN:MAX (or MAX alone: min 0)."""
    if text is None:
        return None, None
    parts = str(text).split(":")
    try:
        lo, hi = (0.0, float(parts[0])) if len(parts) == 1 else (float(parts[0]),
                                                                   float(parts[1]))
    except ValueError:
        raise InputError(f"--speed must be MIN:MAX (numbers), got {text!r}") from None
    if len(parts) > 2 or not (math.isfinite(lo) and math.isfinite(hi)) or not 0 <= lo <= hi \
            or hi <= 0:
        raise InputError(f"--speed must be MIN:MAX with 0 <= MIN <= MAX, MAX > 0, got {text!r}")
    return lo, hi


def _tables(args, attrs):
    """(preset [initiate] table or {}, --config [initiate] table or {})."""
    preset, config = {}, {}
    if args.config:
        config = read_toml(args.config).get("initiate", {})
    elif attrs.get("scenario"):
        from irdetect.simulate.presets import preset_kind
        from irdetect.simulate.scans import load_scan_scenario
        try:
            kind = preset_kind(attrs["scenario"])
        except InputError:
            kind = None                        # not a preset (e.g. "custom")
        if kind == "scans":
            _, preset = load_scan_scenario(attrs["scenario"])
            log.info("initiation parameters of the %s preset (not derived)",
                     attrs["scenario"])
    return preset, config


def resolve(args, scans, attrs) -> tuple[dict, object]:
    """The parameters of a run (and the sensor model): derived from the sensor model,
    overridden by the preset's table, --config's table and the options."""
    from irdetect.initiate.sensor import derive_params, sensor_model

    for option, value in (("--sigma", args.sigma), ("--sigma-range", args.sigma_range),
                          ("--sigma-azimuth", args.sigma_azimuth)):
        if value is not None and not value > 0:     # 0 would read as "not given"
            raise InputError(f"{option} must be a number > 0, got {value:g}")
    preset, config = _tables(args, attrs)
    table = {**preset, **config}
    lo, hi = _speed(args.speed)
    # the sensor model: options, else the file's attributes, else the tables' keys
    fallback = {k: table[t] for k, t in (("sigma", "sigma"), ("sigma_range", "sigma_range"),
                                         ("sigma_azimuth", "sigma_azimuth"),
                                         ("speed_min", "v_min"), ("speed_max", "v_max"))
                if t in table}
    given = {"sigma": args.sigma, "sigma_range": args.sigma_range,
             "sigma_azimuth": (math.radians(args.sigma_azimuth)
                               if args.sigma_azimuth is not None else None),
             "speed_min": lo, "speed_max": hi}
    sources = {**fallback, **{k: v for k, v in attrs.items() if k in given}}
    sensor = sensor_model(sources, path=args.input, **given)
    n_scans = len(set(scans["scan"].tolist()))
    window = args.window if args.window is not None else table.get("window")
    if window is not None and window < 2 and window != 0:
        raise InputError(f"--window must be >= 2, got {window}")
    window = max(2, min(window or n_scans, n_scans)) if window is not None else None
    rate = args.false_tracks
    if rate is not None and not (math.isfinite(rate) and rate >= 0):
        raise InputError(f"--false-tracks must be a number >= 0, got {rate}", args.input)
    if rate is None:
        rate = table.get("false_tracks", 0.0 if preset else 0.05)
    if not (isinstance(rate, (int, float)) and math.isfinite(rate) and rate >= 0):
        raise InputError(f"initiate.false_tracks must be a number >= 0, got {rate!r}",
                         args.config)
    derived = derive_params(sensor, scans, window=window, false_tracks=float(rate))
    # a named preset's table is the paper's tuned setting: it replaces the derivation (over
    # the defaults, as before issue 17); --config overrides single derived parameters
    data = {**(DEFAULTS if preset else derived), **table}
    if args.method:
        data["method"] = args.method
    if args.merge_peaks:
        data["merge_peaks"] = True
    if args.no_verify:
        data["verify"] = False
    if args.false_tracks is not None:
        data["false_tracks"] = args.false_tracks
    data["window"] = derived["window"]
    cfg = from_dict(InitiateConfig, data, where="initiate", path=args.config)
    return dataclasses.asdict(cfg), sensor


#: the most measurements one window may hold: 1.4x the papers' densest scene (zhang2010 at
#: 0.1 clutter points per km^2: 14,425 in 10 scans, 2.6 s); the work grows faster than
#: their number (10,000 uniform points at a 5 s period took 76 s and 5.2 GB on 2 cores,
#: 50,000 ran past 300 s at 20 GB before the clustering's graph was made smaller)
MAX_WINDOW_POINTS = 20_000


def _check_window_size(scan_numbers, windows, path) -> None:
    """Refuse, before any work, a window of more than ``MAX_WINDOW_POINTS`` measurements."""
    s = np.sort(np.asarray(scan_numbers))
    counts = [int(np.searchsorted(s, b, "right") - np.searchsorted(s, a, "left"))
              for a, b in windows]
    if counts and max(counts) > MAX_WINDOW_POINTS:
        raise InputError(f"a window of scans holds {max(counts):,} measurements, at most "
                         f"{MAX_WINDOW_POINTS:,} (the work grows faster than their number): give a "
                         "shorter --window or thin the clutter", path)


def run(args) -> int:
    from irdetect.initiate.sensor import explain_empty
    from irdetect.io import ResultsWriter, check_output_path
    from irdetect.io.scans import read_scans

    check_output_path(args.output, args.force, inputs=(args.input,))
    scans, truth, attrs = read_scans(args.input)
    if args.step is not None and args.step < 1:
        raise InputError(f"--step must be >= 1, got {args.step}")
    params, sensor = resolve(args, scans, attrs)
    n_scans = len(set(scans["scan"].tolist()))
    window = params.pop("window")
    log.info("sensor model: sigma %g, sigma_range %g, sigma_azimuth %g deg, speed %g-%g per s; "
             "parameters: rho cells %.4g, %d theta cells, tile %.4g, %d-scan window, "
             "min_hits %.2f, false_tracks %g", sensor.sigma, sensor.sigma_range,
             math.degrees(sensor.sigma_azimuth), sensor.speed_min, sensor.speed_max,
             params["rho_step"], params["n_theta"], params["tile"], window, params["min_hits"],
             params["false_tracks"])
    if n_scans < 2:
        log.warning("%s holds %d scan(s): a track needs at least 2; no tracks", args.input,
                    n_scans)
    try:
        windows = scan_windows(scans["scan"], window=window, step=args.step)
    except ValueError as exc:
        raise InputError(str(exc)) from None
    _check_window_size(scans["scan"], windows, args.input)
    try:
        tracks = initiate_scans(scans, window=window, step=args.step, **params)
    except ValueError as exc:
        raise InputError(str(exc), args.config) from None
    run_attrs = {"input": str(args.input), "config": json.dumps({"initiate": params}),
                 "window": window, "step": args.step or window,
                 "windows": json.dumps(windows),
                 "scan_times": json.dumps({int(s): float(t) for s, t in
                                           zip(scans["scan"], scans["time"])})}
    for key in ("period", "scenario", "max_range"):
        if key in attrs:
            run_attrs[key] = attrs[key]
    # the sensor model the run used (evaluate scores with it)
    run_attrs.update(sigma=params["sigma"], speed_min=sensor.speed_min,
                     speed_max=sensor.speed_max)
    if params["sigma_azimuth"] > 0:
        run_attrs.update(sigma_range=params["sigma_range"],
                         sigma_azimuth=params["sigma_azimuth"])
    with ResultsWriter(args.output, force=args.force, attrs=run_attrs,
                       inputs=(args.input,)) as out:
        out.write("tracks", tracks)
        out.write("scans", scans)
        if truth is not None:
            out.write("scan_truth", truth)
    if not len(tracks) and n_scans >= 2:
        log.warning("%s: %s", args.input, explain_empty({**params, "window": window}, scans))
    log.info("wrote %s: %d tracks from %d scans in %d window(s) (%s)", args.output,
             len(tracks), n_scans, len(windows), params["method"])
    return 0
