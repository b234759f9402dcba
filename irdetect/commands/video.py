"""Write an annotated video of a sequence and its results, for people to watch.

Every frame is contrast-stretched for display (robust percentiles, 8/16-bit and float
aware, optional gamma) and overlaid with the confirmed detections (circles coloured by
window), optionally the unconfirmed candidates, the initiated tracks (estimated path, a
trail and the id, only over the frames each track spans), frame-by-frame tracker output
when present, and ground truth with --truth; without a results file, the sequence alone.
Output by extension: .mp4 (mp4v), .avi (MJPG), or a folder name without a suffix for PNG
frames. See docs/video.md.
"""

from __future__ import annotations

from pathlib import Path

from irdetect.commands import DATASET_HELP, SEQUENCE_KINDS, TRUTH_KINDS
from irdetect.errors import InputError


def add_arguments(p, *, standalone: bool = True):
    if standalone:
        p.add_argument("input", help=f"sequence: {SEQUENCE_KINDS}")
        p.add_argument("results", nargs="?",
                       help="results file of irdetect process (or track); without it, the "
                       "sequence alone (with --truth, its ground truth: a look at the data "
                       "before a run)")
        p.add_argument("-o", "--output", required=True,
                       help="out.mp4, out.avi, or a folder name (no suffix) for PNG frames")
        p.add_argument("--dataset", help=DATASET_HELP)
        p.add_argument("--force", action="store_true", help="overwrite an existing output")
    add_style_arguments(p)


def add_style_arguments(p):
    """Options shared by `irdetect video` and `irdetect process --video`."""
    g = p.add_argument_group("video")
    g.add_argument("--fps", type=float, help="frames per second (default: the sequence's "
                   "frame rate, else 25)")
    g.add_argument("--scale", type=float, help="output pixels per source pixel (default: "
                   "enough for 640 px width, at most 4)")
    g.add_argument("--every", type=int, default=1, metavar="N", help="write every N-th frame")
    g.add_argument("--truth", nargs="?", const=True, default=None, metavar="FILE",
                   help="draw ground truth in green: alone, the sequence's /truth or its "
                   f"recording folder's truth.txt; or FILE ({TRUTH_KINDS})")
    g.add_argument("--candidates", action="store_true",
                   help="also draw unconfirmed candidates (small grey crosses)")
    g.add_argument("--panels", action="store_true",
                   help="raw | suppressed | combined frame side by side")
    g.add_argument("--gamma", type=float, default=1.0,
                   help="display gamma (< 1 brightens dark pixels; default 1)")
    g.add_argument("--percentiles", type=float, nargs=2, default=(0.5, 99.8),
                   metavar=("LOW", "HIGH"), help="display limits (default 0.5 99.8)")
    g.add_argument("--trail", type=int, default=12, help="frames of trail behind a track")
    g.add_argument("--no-legend", dest="legend", action="store_false",
                   help="no status strip (frame number, counts, legend) below the picture")


def resolve_truth(option, source):
    """The truth table asked for by --truth (None when not asked): ``--truth FILE``, or
    with a bare ``--truth`` the sequence's own (``irdetect.io.find_truth``)."""
    from irdetect.io import find_truth

    if option is None:
        return None
    given = None if option is True else option
    return find_truth(given, sequence=source, n_frames=len(source)).table


def render(source, results, output, args, *, force: bool):
    """Run ``irdetect.render.write_video`` with the style options of ``args``."""
    from irdetect.render import write_video

    low, high = args.percentiles
    return write_video(source, results, output, fps=args.fps, scale=args.scale,
                       every=args.every, truth=resolve_truth(args.truth, source),
                       candidates=args.candidates, panels=args.panels, gamma=args.gamma,
                       low=low, high=high, trail=args.trail, legend=args.legend,
                       force=force, progress=args.progress)


def render_after_process(input, results_path, args) -> dict:
    """`irdetect process --video OUT`: render the results just written."""
    from irdetect.io import open_sequence, read_results

    results = read_results(results_path)
    with open_sequence(input, args.dataset) as src:
        return render(src, results, args.video, args, force=args.force)


def run(args) -> int:
    from irdetect.io import open_sequence, read_results
    from irdetect.io.video import check_video_path

    check_video_path(args.output, args.force)
    results = None
    if args.results is not None:
        if not Path(args.results).exists():
            raise InputError("results file not found", args.results)
        results = read_results(args.results)
    with open_sequence(args.input, args.dataset) as src:
        render(src, results, args.output, args, force=args.force)
    return 0
