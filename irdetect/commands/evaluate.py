"""Score a results file against ground truth.

Truth comes from ``--truth`` (a sequence file with /truth, a point-annotation text file
``x y`` per frame, or a folder of frames with ``truth.txt`` in it or in its parent),
else from the results file's own input when that has /truth or such a ``truth.txt``.
Each section scores one table when the results file holds it:

  detection   /detections  Pd per window (one-to-one within --gate px of the true path),
                           false detections per window and per megapixel-window,
                           pixel-level Fa (IRSTD convention, 3x3 px per detection)
  track initiation /tracks   Pt per target and overall, Pc, velocity error (lines within
                           3 sigma of every true position, one-to-one; docs/initiation.md);
                           pt_path, n_false_path: the track's position in each of its
                           frames within 2 x --gate of the target in 80 % of them
                           /tracks of irdetect initiate (scans; or the deprecated
                           /scan_tracks): the same per window, OSPA, GOSPA

Other sections (initiated tracks, frame-by-frame tracks) register in ``SECTIONS``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from irdetect.errors import InputError
from irdetect.io import open_sequence, read_point_annotations, read_results


def add_arguments(p):
    p.add_argument("results", help="results file written by irdetect process")
    p.add_argument("--truth", help="sequence file with /truth, a text file of 'x y' per "
                   "frame, or a folder of frames with truth.txt in it or beside it (default: "
                   "the results file's input, when it has truth)")
    p.add_argument("--gate", type=float, default=3.0,
                   help="match distance in px between a detection and the true path (3)")
    p.add_argument("--json", action="store_true", help="print the scores as JSON")


# --- sections: (name, table it needs, function(results, truth, context) -> dict) -------

def _detection_section(results, truth, ctx) -> dict:
    from irdetect.metrics.detection import score_detections

    return score_detections(results["detections"], truth, n_frames=ctx["n_frames"],
                            length=ctx["length"], step=ctx["step"], shape=ctx["shape"],
                            gate=ctx["gate"])


def _mot_section(results, truth, ctx) -> dict:
    """CLEAR-MOT (MOTA, MOTP in px), IDF1 and id switches of /track_points (irdetect track)."""
    from irdetect.metrics.mot import clear_mot

    return clear_mot(truth, results["track_points"], gate=ctx["gate"])


#: Sections run in order, each when its table is in the results file. Add yours here:
#: ``(title, table name, function(results, truth, context) -> dict of scores)``; the
#: context holds n_frames, length, step, shape (H, W), gate, frame_rate.
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


def evaluate(results_path, truth_path=None, *, gate: float = 3.0) -> dict:
    """Scores of a results file: ``{section: {metric: value}}``.

    Raises
    ------
    InputError
        Unreadable files, no truth to be found, or a results file without any table a
        section can score.
    """
    if not math.isfinite(gate) or gate <= 0:
        raise InputError(f"--gate must be a positive number, got {gate}")
    results = read_results(results_path)
    from irdetect.metrics.initiation import evaluate_scan_results, scan_tracks_of
    if scan_tracks_of(results, warn=False) is not None:     # initiate on scans: scans truth
        return {"track initiation (scans)": evaluate_scan_results(results, truth_path)}
    truth, seq_shape = _load_truth(results, results_path, truth_path)
    attrs = results.attrs
    cfg = results.config.get("combine", {})
    length = int(attrs.get("combined_length", cfg.get("length", 12)))
    step = int(attrs.get("combined_step", cfg.get("step", length)))
    if "frame_height" in attrs:
        shape = (int(attrs["frame_height"]), int(attrs["frame_width"]))
        n_frames = int(attrs["n_frames"])
    elif seq_shape is not None:
        n_frames, shape = seq_shape[0], seq_shape[1:]
    else:
        raise InputError("results file does not say the frame size (attrs frame_height, "
                         "frame_width, n_frames) and --truth is not a sequence", results_path)
    ctx = {"n_frames": n_frames, "length": length, "step": step, "shape": shape,
           "gate": float(gate), "frame_rate": attrs.get("frame_rate")}
    out = {}
    for title, table, function in SECTIONS:
        if table in results:
            out[title] = function(results, truth, ctx)
    if not out:
        raise InputError(f"nothing to score: no {', '.join(t for _, t, _ in SECTIONS)} table",
                         results_path)
    return out


def _load_truth(results, results_path, truth_path):
    """(TRUTH table, sequence shape or None)."""
    if truth_path is None:
        candidates = [results.attrs.get("input_path"), results.attrs.get("input")]
        folder = Path(results_path).resolve().parent
        for name in filter(None, candidates):
            for path in (Path(name), folder / name):
                if path.exists():
                    truth_path = path
                    break
            if truth_path is not None:
                break
        if truth_path is None:
            raise InputError("no --truth given and the results' input file was not found",
                             results_path)
    p = Path(truth_path)
    if p.is_dir():
        # a folder of frames: its point annotations sit in it or beside it
        # (../shared/data/real/NAME/{frames/, truth.txt})
        found = [q / "truth.txt" for q in (p, p.parent) if (q / "truth.txt").is_file()]
        if not found:
            raise InputError("a folder of frames has no truth.txt in it or beside it; "
                             "give --truth ANNOTATIONS.txt", p)
        p = found[0]
    if p.suffix.lower() in (".txt", ".csv"):
        return read_point_annotations(p), None
    with open_sequence(p) as src:
        if src.truth is None:
            raise InputError("has no /truth to score against", p)
        return src.truth, tuple(src.shape)


def format_table(scores: dict) -> str:
    """Plain-text table, one block per section."""
    lines = []
    for title, values in scores.items():
        lines.append(f"{title}")
        for key, value in values.items():
            if isinstance(value, float):
                text = f"{value:.4g}" if abs(value) >= 1e-3 or value == 0 else f"{value:.3e}"
            else:
                text = str(value)
            lines.append(f"  {key:<22} {text}")
    return "\n".join(lines)


def run(args) -> int:
    scores = evaluate(args.results, args.truth, gate=args.gate)
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
