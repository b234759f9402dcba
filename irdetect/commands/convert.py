"""Convert any readable sequence (HDF5, folder of images, multi-page TIFF, video, .npy,
MAT-file) to the HDF5 contract.

With --truth, a point annotation file (one 'x y' line per frame, x = column, y = row,
0-based; the format of shared/data/real/*/truth.txt) or a folder of target masks (one
binary image per frame, each region a target at its centroid) is imported as /truth.
"""

from __future__ import annotations

import logging

from tqdm import tqdm

from irdetect.commands import DATASET_HELP, SEQUENCE_KINDS
from irdetect.errors import InputError
from irdetect.io import check_output_path, open_sequence, write_sequence
from irdetect.io.sources import check_values
from irdetect.io.truth import find_truth

log = logging.getLogger(__name__)


def add_arguments(p):
    p.add_argument("input", help=SEQUENCE_KINDS)
    p.add_argument("-o", "--output", required=True, help="HDF5 file to write")
    p.add_argument("--truth", help="point annotation file, one 'x y' line per frame, or a "
                   "folder of target masks, one binary image per frame")
    p.add_argument("--dataset", help=DATASET_HELP)
    p.add_argument("--frame-rate", type=float, help="frames per second to record")
    p.add_argument("--force", action="store_true", help="overwrite an existing output")


def run(args) -> int:
    if args.frame_rate is not None and not args.frame_rate > 0:
        raise InputError(f"--frame-rate must be > 0, got {args.frame_rate}")
    inputs = (args.input, args.truth)
    with open_sequence(args.input, args.dataset) as src:     # a missing input is said first
        check_output_path(args.output, args.force, inputs)
        truth = (find_truth(args.truth, n_frames=len(src)).table if args.truth else src.truth)
        bar = tqdm(total=len(src), unit="frame", disable=not args.progress, desc="convert")

        def blocks():
            for start, frames in src.windows(64):
                # values beyond float32's range are kept as stored (process refuses them)
                check_values(frames, start, args.input, limit=None)
                bar.update(len(frames))
                yield frames

        rate = args.frame_rate or src.frame_rate
        attrs = {"source": str(args.input)} | ({"frame_rate": rate} if rate else {})
        write_sequence(args.output, blocks(), truth=truth, attrs=attrs, force=args.force,
                       inputs=inputs)
        bar.close()
        log.info("wrote %s: %d frames of %dx%d %s%s", args.output, len(src), src.shape[2],
                    src.shape[1], src.dtype, f", {len(truth)} truth rows" if truth is not None
                    else "")
    return 0
