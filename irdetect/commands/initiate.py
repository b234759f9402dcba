"""Initiate tracks on radar-style measurement scans (/scans) in a sliding window of M scans.

Methods: hough-sc (Hough + subtractive clustering, Zhang et al. 2010), hough (plain
threshold), nms (greedy non-maximum suppression), opencv (cv2.HoughLinesPointSet),
parallel-hough, fuzzy-parallel-hough (Liang et al. 2015), mn-logic (M-of-N logic).
Parameters come from --config (a TOML file with an [initiate] table), else from the
preset of the scenario named in the scans file, else the defaults; options override them.
Writes /scan_tracks (docs/initiation.md).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math

from irdetect.config import InitiateConfig, from_dict, read_toml
from irdetect.errors import InputError
from irdetect.initiate import METHODS, initiate_scans, scan_windows

log = logging.getLogger(__name__)


def add_arguments(p):
    p.add_argument("input", help="scans file (HDF5 with /scans: scan, time, x, y)")
    p.add_argument("-o", "--output", required=True, help="results file to write")
    p.add_argument("--method", choices=METHODS, help="initiation method (default: hough-sc "
                   "or the scenario preset's)")
    p.add_argument("--window", type=int, default=None,
                   help="sliding window length M in scans (default: the config's "
                   "initiate.window, 10; all scans when there are fewer)")
    p.add_argument("--step", type=int, default=None, help="scans between windows (default M)")
    p.add_argument("--config", help="TOML file with an [initiate] table")
    p.add_argument("--merge-peaks", action="store_true",
                   help="merge the cells of a peak by subtractive clustering (parallel methods)")
    p.add_argument("--no-verify", action="store_true",
                   help="paper form: every selected cell is a track (no constant-velocity check)")
    p.add_argument("--force", action="store_true", help="overwrite an existing output")


def _params(args, attrs) -> dict:
    data = {}
    if args.config:
        data = read_toml(args.config).get("initiate", {})
    elif attrs.get("scenario"):
        from irdetect.simulate.presets import preset_kind
        from irdetect.simulate.scans import load_scan_scenario
        if preset_kind(attrs["scenario"]) == "scans":
            _, data = load_scan_scenario(attrs["scenario"])
            log.info("initiation parameters of the %s preset", attrs["scenario"])
    if args.method:
        data["method"] = args.method
    if args.merge_peaks:
        data["merge_peaks"] = True
    if args.no_verify:
        data["verify"] = False
    cfg = from_dict(InitiateConfig, data, where="initiate", path=args.config)
    return dataclasses.asdict(cfg)


def run(args) -> int:
    from irdetect.io import ResultsWriter, check_output_path
    from irdetect.io.scans import read_scans

    check_output_path(args.output, args.force, inputs=(args.input,))
    scans, truth, attrs = read_scans(args.input)
    params = _params(args, attrs)
    n_scans = len(set(scans["scan"].tolist()))
    window = params.pop("window")       # the config's M (0 = all scans)
    window = args.window if args.window is not None else max(2, min(window or n_scans,
                                                                     n_scans))
    if window < 2:
        raise InputError(f"--window must be >= 2, got {window}")
    if args.step is not None and args.step < 1:
        raise InputError(f"--step must be >= 1, got {args.step}")
    if n_scans < 2:
        log.warning("%s holds %d scan(s): a track needs at least 2; no tracks", args.input,
                    n_scans)
    try:
        tracks = initiate_scans(scans, window=window, step=args.step, **params)
    except ValueError as exc:
        raise InputError(str(exc), args.config) from None
    windows = scan_windows(scans["scan"], window=window, step=args.step)
    run_attrs = {"input": str(args.input), "config": json.dumps({"initiate": params}),
                 "window": window, "step": args.step or window,
                 "windows": json.dumps(windows),
                 "scan_times": json.dumps({int(s): float(t) for s, t in
                                           zip(scans["scan"], scans["time"])})}
    for key in ("sigma", "sigma_range", "sigma_azimuth", "period", "scenario", "max_range"):
        if key in attrs:
            run_attrs[key] = attrs[key]
    with ResultsWriter(args.output, force=args.force, attrs=run_attrs,
                       inputs=(args.input,)) as out:
        out.write("scan_tracks", tracks)
        out.write("scans", scans)
        if truth is not None:
            out.write("scan_truth", truth)
    log.info("wrote %s: %d tracks from %d scans in %d window(s) (%s)", args.output,
             len(tracks), n_scans, len(windows), params["method"])
    if not math.isfinite(len(tracks)):
        return 1
    return 0
