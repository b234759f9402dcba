"""Detect dim point targets in a sequence and initiate their tracks.

Suppresses clutter, forms combined frames, runs directional threshold detection, fuses
target groups, confirms them by bidirectional correlation over 3 combined frames and
initiates tracks by Hough transform + subtractive clustering. Writes one HDF5 results
file (/detections, /candidates, /segments, /tracks; docs/format.md).
"""

from __future__ import annotations

import logging
from pathlib import Path

from irdetect.config import load_config
from irdetect.commands.video import add_style_arguments as add_video_arguments
from irdetect.commands.video import render_after_process
from irdetect.io.video import check_video_path

log = logging.getLogger(__name__)


def add_arguments(p):
    p.add_argument("input", help="sequence: HDF5 file, folder of images, video file or .npy")
    p.add_argument("-o", "--output",
                   help="results file (default: INPUT_NAME.irdetect.h5 in the current folder)")
    p.add_argument("--config", help="TOML file with one table per stage (docs/cli.md)")
    p.add_argument("--dataset", help="HDF5 input: dataset path (default /frames)")
    p.add_argument("--force", action="store_true", help="overwrite an existing output")
    p.add_argument("--video", metavar="OUT", help="single input: also write the annotated "
                   "video (.mp4, .avi or a PNG folder; options below, docs/video.md)")
    add_video_arguments(p)


def default_output(input_path) -> Path:
    """``<input name>.irdetect.h5`` in the current folder."""
    path = Path(input_path)
    name = path.name if path.is_dir() else path.stem
    return Path(f"{name}.irdetect.h5")


def run(args) -> int:
    config = load_config(args.config)
    from irdetect.pipeline import process_file

    output = args.output or default_output(args.input)
    if args.video:
        check_video_path(args.video, args.force)       # fail before the long run
    summary = process_file(args.input, output, config, dataset=args.dataset, force=args.force,
                           progress=args.progress)
    log.info("wrote %s: %d frames, %d detections, %d tracks in %.1f s", output,
                summary["frames"], summary["detections"], summary["tracks"], summary["seconds"])
    if args.video:
        render_after_process(args.input, output, args)
    return 0
