"""Write a results file's tables in formats other tools read.

csv: detections.csv, tracks.csv and track_positions.csv (each track's x, y in every frame
of its span). mot: tracks_mot.txt in the MOTChallenge text format (frame, id, bb_left,
bb_top, bb_width, bb_height, conf, x, y, z; frames and pixels counted from 1 as MOT does,
a square box of --box px centred on each point), read by TrackEval and py-motmetrics.
json: results.json, the attributes, the configuration and every table. mat: results.mat
for MATLAB, every table a struct of column vectors (values counted from 0, as in the
results file). Existing files are kept unless --force. See docs/format.md.
"""

from __future__ import annotations

import logging
from pathlib import Path

from irdetect.errors import InputError

log = logging.getLogger(__name__)


def add_arguments(p):
    from irdetect.export import FORMATS, MOT_BOX

    p.add_argument("results", help="results file of irdetect process or irdetect track")
    p.add_argument("--format", required=True, choices=FORMATS, help="what to write")
    p.add_argument("-o", "--output", required=True, metavar="DIR",
                   help="folder for the files (created when missing)")
    p.add_argument("--box", type=float, default=MOT_BOX,
                   help=f"mot: side in px of the box around each point (default {MOT_BOX:g})")
    p.add_argument("--force", action="store_true", help="overwrite existing files")


def run(args) -> int:
    from irdetect.export import export_results
    from irdetect.io import read_results

    if not args.box > 0:
        raise InputError(f"--box must be a positive number of px, got {args.box}")
    if not Path(args.results).exists():
        raise InputError("results file not found", args.results)
    written = export_results(read_results(args.results), args.output, args.format,
                             box=args.box, force=args.force)
    log.info("wrote %s", ", ".join(str(p) for p in written))
    return 0
