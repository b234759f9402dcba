"""Score a results file against ground truth.

Reads the results of irdetect process (detections, initiated tracks), irdetect track
(frame-by-frame tracks) or irdetect initiate (tracks on radar-style scans), and scores each
table it holds:

  detection         Pd per window (a detection within --gate px of the true path, one
                    to one), false detections per window and per megapixel-window,
                    pixel-level false-alarm rate (3x3 px per false detection); with
                    --presence, a target inside the frame in fewer of a window's frames
                    does not count there, and its detections are set aside
  track initiation  Pt per target and overall, Pc (share of false tracks), speed error;
                    pt_path: a track within 2 x --gate px of its target in 80 % of its
                    frames, and false_path_tracks: the ids of the tracks false by it;
                    on scans the same per window, and OSPA, GOSPA
  tracking          CLEAR-MOT (MOTA, MOTP in px), IDF1 and identity switches
  IRSTD (--irstd)   Pd and Fa as infrared small-target papers compute them from masks
                    (pyirstdmetrics): a target is detected when a predicted region's
                    centroid lies within --gate px of its own (3 px in the field), Fa =
                    pixels of unmatched regions / all pixels; points are drawn as discs
                    (docs/format.md says which definition each figure uses)

Truth comes from --truth, else from the sequence the results were made from: its /truth,
or the truth.txt of its recording folder. A legend line under the table says what each
figure means.
"""

from __future__ import annotations

import json
import math

import numpy as np

from irdetect import tables
from irdetect.commands import TRUTH_KINDS
from irdetect.errors import InputError
from irdetect.io import read_results


def add_arguments(p):
    import argparse

    p.formatter_class = argparse.RawDescriptionHelpFormatter    # keep the list above as is
    p.add_argument("results", help="results file of irdetect process, track or initiate")
    p.add_argument("--truth", metavar="FILE",
                   help=f"{TRUTH_KINDS} (default: the results' input sequence: its /truth "
                   "or its recording folder's truth.txt)")
    p.add_argument("--gate", type=float, default=3.0,
                   help="match distance in px between a detection and the true path (3)")
    p.add_argument("--presence", type=float, default=0.0, metavar="SHARE",
                   help="a target counts in a window only when it is inside the frame in "
                   "this share of the window's frames, and a detection of one inside for "
                   "less is set aside, neither detected nor false (0: every target, the "
                   "default; the benchmarks use 0.75)")
    p.add_argument("--json", action="store_true", help="print the scores as JSON")
    p.add_argument("--irstd", action="store_true",
                   help="also Pd and Fa as the IRSTD field computes them from masks "
                   "(pyirstdmetrics), to set beside a paper's table")


# --- sections: (name, table it needs, function(results, truth, context) -> dict) -------

def _detection_section(results, truth, ctx) -> dict:
    from irdetect.metrics.detection import roc, score_detections

    det = results["detections"]
    kw = dict(n_frames=ctx["n_frames"], length=ctx["length"], step=ctx["step"],
              shape=ctx["shape"], gate=ctx["gate"], tail=ctx["tail"], presence=ctx["presence"])
    out = score_detections(det, truth, **kw)
    out["false_per_frame"] = out["false"] / ctx["n_frames"]
    if "snr" in det.dtype.names:          # results of irdetect 0.x before the per-frame path
        curve = roc(det, truth, **kw)
        out["roc_auc"] = curve["auc"]
        out["roc"] = {k: curve[k] for k in ("thresholds", "pd", "false_per_frame")}
    return out


def _mot_section(results, truth, ctx) -> dict:
    """CLEAR-MOT (MOTA, MOTP in px), IDF1 and id switches of /track_points (irdetect track)."""
    from irdetect.metrics.mot import clear_mot

    return clear_mot(truth, results["track_points"], gate=ctx["gate"])


#: Sections run in order, each when its table is in the results file (add new scores
#: here, and their meaning to LEGEND):
#: ``(title, table name, function(results, truth, context) -> dict of scores)``; the
#: context holds n_frames, length, step, tail, shape (H, W), gate, frame_rate, presence.
def _initiation_section(results, truth, ctx) -> dict:
    """Pt per target and overall, Pc and velocity error of /tracks (irdetect process;
    the frame-by-frame tracker's /tracks, beside /track_points, are scored by CLEAR-MOT)."""
    from irdetect.metrics.initiation import evaluate_image_tracks

    if "track_points" in results:
        return {"skipped": "tracks of irdetect track: see tracking (CLEAR-MOT)"}
    return evaluate_image_tracks(results, truth, gate=ctx["gate"])


SECTIONS: list[tuple[str, str, callable]] = [
    ("detection", "detections", _detection_section),
    ("tracking (CLEAR-MOT)", "track_points", _mot_section),
    ("track initiation", "tracks", _initiation_section),
]


def evaluate(results_path, truth_path=None, *, gate: float = 3.0,
             irstd: bool = False, presence: float = 0.0) -> dict:
    """Scores of a results file: ``{section: {metric: value}}``; ``irstd`` adds the
    section of ``irdetect.metrics.irstd`` (IRSTD Pd / Fa); ``presence``: the detection
    section's presence rule (``irdetect.metrics.detection.score_detections``).

    Raises
    ------
    InputError
        Unreadable files, no truth to be found, or a results file without any table a
        section can score.
    """
    if not math.isfinite(gate) or gate <= 0:
        raise InputError(f"--gate must be a positive number, got {gate}")
    if not 0 <= presence <= 1:
        raise InputError(f"--presence must lie in [0, 1], got {presence}")
    results = read_results(results_path)
    from irdetect.metrics.initiation import evaluate_scan_results, scan_tracks_of
    if scan_tracks_of(results, warn=False) is not None:     # initiate on scans: scans truth
        if irstd:
            raise InputError("--irstd scores image detections; this holds tracks on scans",
                             results_path)
        return {"track initiation (scans)": evaluate_scan_results(results, truth_path)}
    truth, seq_shape = _load_truth(results, results_path, truth_path)
    attrs = results.attrs
    length, step, tail = results.windows()
    if "frame_height" in attrs:
        shape = (int(attrs["frame_height"]), int(attrs["frame_width"]))
        n_frames = int(attrs["n_frames"])
    elif seq_shape is not None:
        n_frames, shape = seq_shape[0], seq_shape[1:]
    else:
        raise InputError("results file does not say the frame size (attrs frame_height, "
                         "frame_width, n_frames) and --truth is not a sequence", results_path)
    ctx = {"n_frames": n_frames, "length": length, "step": step, "tail": tail, "shape": shape,
           "gate": float(gate), "frame_rate": attrs.get("frame_rate"),
           "presence": float(presence)}
    out = {}
    for title, table, function in SECTIONS:
        if table in results:
            missing = set(tables.BY_NAME[table].names) - set(results[table].dtype.names)
            if missing:
                raise InputError(f"/{table} lacks the fields {sorted(missing)}", results_path)
            out[title] = function(results, truth, ctx)
    if not out:
        raise InputError(f"nothing to score: no {', '.join(t for _, t, _ in SECTIONS)} table",
                         results_path)
    if irstd:
        from irdetect.metrics.irstd import irstd_section
        out["IRSTD (pyirstdmetrics)"] = irstd_section(results, truth, ctx, results_path)
    return out


def _load_truth(results, results_path, truth_path):
    """(TRUTH table, sequence shape or None): ``--truth``, else the truth of the results'
    input sequence, by the rule of ``irdetect.io.find_truth``."""
    from irdetect.commands import find_sequence
    from irdetect.io import find_truth

    sequence = None
    if truth_path is None:
        sequence = find_sequence(results)
        if sequence is None:
            raise InputError("no --truth given and the results' input file was not found",
                             results_path)
    found = find_truth(truth_path, sequence=sequence, n_frames=results.attrs.get("n_frames"))
    return found.table, found.shape


#: what a figure of the table means, with its unit: printed, for the figures shown, on one
#: line under the table
LEGEND = {
    "pd": "pd = detected / target-windows",
    "roc_auc": "roc_auc = area under pd vs false/frame (0-0.1) over snr thresholds / 0.1",
    "false": "false = detections near no target",
    "set_aside": "set_aside = detections of a target inside the frame in under --presence "
                 "of its window's frames (neither detected nor false)",
    "pixel_fa": "pixel_fa = false-alarm pixels / all pixels (3x3 px per false detection)",
    "pt_overall": "pt = targets with a track / targets, by the paper's line rule (every "
                  "true position within 3 x initiate.sigma, 4.5 px by default, of the "
                  "track's line: a target that turns fails it)",
    "pc": "pc = false tracks / tracks (line rule)",
    "speed_error_median": "speed_error = |track - true velocity| / true speed",
    "pt_path": "pt_path = pt by the path rule: a track within 2 x gate of its target in "
               "80 % of its frames (what the benchmarks score)",
    "false_path_tracks": "false_path_tracks = track_id of the tracks false by that rule "
                         "(following no target, or a second one on a target over the "
                         "same frames)",
    "mota": "mota = 1 - (misses + false + switches) / true positions",
    "motp": "motp = mean distance of the matches (px)",
    "ospa_mean": "ospa = optimal subpattern assignment distance per window (m)",
    "gate": "gate = match distance (px)",
    "irstd_pd": "irstd_pd = targets a region's centroid is within distance of / targets",
    "irstd_fa": "irstd_fa = pixels of unmatched regions / all pixels",
}


def legend_line(scores: dict) -> str:
    """One line saying what the figures of ``scores`` mean (those in ``LEGEND``)."""
    keys = {key for values in scores.values() for key in values}
    return "legend: " + "; ".join(text for key, text in LEGEND.items() if key in keys)


#: the false detections per frame at which the plain-text table gives the ROC's Pd
ROC_RATES = (0.0, 0.001, 0.01, 0.1)


def format_table(scores: dict) -> str:
    """Plain-text table, one block per section, and the legend line under it (a ROC
    curve as its best Pd at a few false-alarm rates, ``ROC_RATES``, and with every
    detection; the whole curve is in ``--json``)."""
    lines = []
    for title, values in scores.items():
        lines.append(f"{title}")
        for key, value in values.items():
            if isinstance(value, dict):           # the ROC's columns
                lines += _roc_lines(key, value)
                continue
            lines.append(f"  {key:<22} {_number(value)}")
    lines.append(legend_line(scores))
    return "\n".join(lines)


def _roc_lines(key: str, curve: dict) -> list[str]:
    """The ROC's rows at ``ROC_RATES``: the best Pd of a threshold with at most that many
    false detections per frame, and that threshold; then every detection's row."""
    pd, rate = np.asarray(curve["pd"], float), np.asarray(curve["false_per_frame"], float)
    thresholds = np.asarray(curve["thresholds"], float)
    lines = [f"  {key:<22} {'false/frame <=':>15}  {'pd':>15}  {'snr >=':>15}"]
    rows = []
    for limit in ROC_RATES:
        ok = np.flatnonzero(rate <= limit)
        if len(ok):
            best = ok[np.argmax(pd[ok])]
            rows.append((_number(limit), pd[best], thresholds[best]))
    if len(pd):
        rows.append(("all", pd[-1], thresholds[-1]))
    lines += [f"  {'':<22} {a:>15}  {_number(b):>15}  {_number(c):>15}" for a, b, c in rows]
    lines.append(f"  {'':<22} (the whole curve: --json, or irdetect plot --roc)")
    return lines


def _number(value) -> str:
    if isinstance(value, float):
        return f"{value:.4g}" if abs(value) >= 1e-3 or value == 0 else f"{value:.3e}"
    return str(value)


def run(args) -> int:
    scores = evaluate(args.results, args.truth, gate=args.gate, irstd=args.irstd,
                      presence=args.presence)
    if args.json:
        print(json.dumps(_no_nan(scores), indent=2, default=_plain))
    else:
        print(format_table(scores))
    return 0


def _no_nan(value):
    """NaN (e.g. Pd with no target) becomes null, so the output is strict JSON."""
    if isinstance(value, dict):
        return {k: _no_nan(v) for k, v in value.items()}
    if isinstance(value, float) and math.isnan(value):
        return None
    return value


def _plain(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(type(value).__name__)
