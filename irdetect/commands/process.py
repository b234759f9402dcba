"""Detect dim point targets in a sequence and initiate their tracks.

Suppresses clutter, forms combined frames, runs directional threshold detection, fuses
target groups, confirms them by bidirectional correlation over 3 combined frames; beside
that, finds each frame's CFAR peaks and initiates them like radar scans (the per-frame
path, for bright or fast targets); fuses both paths' detections per window and initiates
tracks by Hough transform + subtractive clustering. Writes one HDF5 results file
(/detections with the path that found each, /tracks, /combined_detections,
/frame_detections, /frame_tracks, /candidates, /segments; docs/format.md).

Several inputs (files, folders of sequences, globs) with --out-dir DIR: one results file
per input, run on --jobs local processes or a Dask cluster (--scheduler), resumable, with
a summary table (DIR/irdetect-summary.csv and .json; docs/batch.md).
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

from irdetect.commands import (DATASET_HELP, SEQUENCE_KINDS, add_input_options,
                               flat_frames, with_input_options)
from irdetect.batch import SCHEDULER_ENV, expand_inputs, is_image_folder, output_name
from irdetect.profiles import load_profile, profile_names
from irdetect.commands.video import add_style_arguments as add_video_arguments
from irdetect.commands.video import render_after_process
from irdetect.io.video import check_video_path
from irdetect.errors import InputError

log = logging.getLogger(__name__)

#: ``--threads`` default: best measured on 2 cores (docs/results/throughput.md)
DEFAULT_THREADS = 2


def add_arguments(p):
    p.add_argument("inputs", nargs="+", metavar="INPUT",
                   help=f"sequence: {SEQUENCE_KINDS}; several inputs, folders of sequences "
                   "or glob patterns with --out-dir")
    p.add_argument("-o", "--output",
                   help="results file of a single input (default: INPUT_NAME.irdetect.h5 in "
                   "the current folder)")
    p.add_argument("--out-dir", metavar="DIR",
                   help="batch: one INPUT_NAME.irdetect.h5 per input in DIR (created if "
                   "missing), a summary table beside them; finished inputs are skipped")
    p.add_argument("-j", "--jobs", type=int, metavar="N",
                   help="batch: local worker processes (default: the core count)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="batch: Dask scheduler address (tcp://host:8786) or scheduler JSON "
                   f"file (default: ${SCHEDULER_ENV}); needs irdetect[distributed]")
    p.add_argument("--config", help="TOML file with one table per stage (docs/cli.md); "
                   "with --profile, applied on top of the profile")
    p.add_argument("--profile", default="default", metavar="NAME",
                   help=f"named configuration: {', '.join(profile_names())} (default: "
                   "default; fast: no matched-filter verification and no fast band, "
                   "3-4x the frames per CPU-second, for targets of SNR >= 3 up to about 2 "
                   "px/frame; docs/cli.md)")
    p.add_argument("--threads", type=int, metavar="N",
                   help=f"single input: threads over windows (default {DEFAULT_THREADS}: the "
                   "correlation of each window triple runs beside the next windows' front "
                   "end); the results do not depend on it")
    p.add_argument("--dataset", help=DATASET_HELP)
    add_input_options(p)
    p.add_argument("--force", action="store_true",
                   help="overwrite an existing output (batch: redo finished inputs)")
    p.add_argument("--video", metavar="OUT", help="single input: also write the annotated "
                   "video (.mp4, .avi or a PNG folder; options below, docs/video.md)")
    add_video_arguments(p)


def run(args) -> int:
    from irdetect.pipeline import check_config, process_file

    config = with_input_options(load_profile(args.profile, args.config), args)
    check_config(config, args.config)         # a bad value fails now, not mid-run
    if args.video and _is_batch(args):
        raise InputError("--video needs a single input (use `irdetect video` per result)")
    if args.threads is not None and args.threads < 1:
        raise InputError(f"--threads must be >= 1, got {args.threads}")
    if _is_batch(args):
        if args.threads is not None:
            raise InputError("--threads is for a single input (a batch runs --jobs processes "
                             "of one thread each)")
        return run_batch(args, config)
    args.input = args.inputs[0]
    output = args.output or output_name(args.input)  # in the current folder
    if args.video:
        check_video_path(args.video, args.force)       # fail before the long run
    summary = process_file(args.input, output, config, dataset=args.dataset, force=args.force,
                           progress=args.progress, workers=args.threads or DEFAULT_THREADS)
    log.info("wrote %s: %d frames, %d detections, %d tracks in %.1f s", output,
             summary["frames"], summary["detections"], summary["tracks"], summary["seconds"])
    flat = flat_frames(args.input, args.dataset) if not summary["detections"] else None
    if flat:
        log.info("no detection: %s", flat)
    elif not summary["detections"] and config.suppress.polarity == "bright":
        log.info("no detection: targets darker than their background (a recording saved "
                 "black-hot) are found with --polarity dark")
    if args.video:
        render_after_process(args.input, output, args)
    return 0


def _is_batch(args) -> bool:
    """Batch mode: --out-dir, several inputs, or one input that is a pattern or a folder
    of sequences (a folder of images is one sequence)."""
    if args.jobs is not None and args.jobs < 1:
        raise InputError(f"--jobs must be >= 1, got {args.jobs}")
    if args.out_dir is not None:
        if args.output is not None:
            raise InputError("give either -o OUT.h5 (one input) or --out-dir DIR, not both")
        return True
    if len(args.inputs) == 1:
        path = Path(args.inputs[0])
        pattern = not path.exists() and any(c in args.inputs[0] for c in "*?[")
        if not pattern and (not path.is_dir() or is_image_folder(path)):
            return False
        if path.is_dir():
            expand_inputs([path])       # a folder holding no sequence: named, exit 2
    what = (f"{len(args.inputs)} inputs" if len(args.inputs) > 1
            else "a folder of sequences or a pattern")
    raise InputError(f"{what}: give --out-dir DIR for the results"
                     + (" (-o names the output of a single input)" if args.output else ""))


def run_batch(args, config) -> int:
    """Process every input into ``args.out_dir``; exit code 1 when any input failed."""
    from irdetect.batch import format_summary, run_batch as batch

    scheduler = args.scheduler or os.environ.get(SCHEDULER_ENV)
    if scheduler and not args.verbose:
        _quiet_dask()
    report = batch(args.inputs, args.out_dir, config, dataset=args.dataset, force=args.force,
                   jobs=args.jobs, scheduler=scheduler,
                   progress=args.progress)
    if not args.quiet:
        print(format_summary(report))
    return 1 if report.failed else 0


def _quiet_dask() -> None:
    """Keep Dask's own log lines (lost workers and connections, tracebacks included) off
    the terminal: the summary says what happened to each input. ``-v`` shows them."""
    try:
        import distributed  # noqa: F401 -- importing it sets its loggers' levels; set ours after
    except ImportError:
        return                  # run_batch says how to install it
    for name in ("distributed", "distributed.client"):
        logging.getLogger(name).setLevel(logging.CRITICAL)
