"""Draw one figure of a results file: the tracks over the max projection of the sequence
(left, with a legend) and the Hough accumulator of the detections with its candidate cells
and the subtractive-clustering centres (right, rho and theta axes, a colour bar of the
votes) -- the picture of peak clustering and its fix; for the results of irdetect track,
the tracker's paths over the max projection. Needs matplotlib (pip install irdetect[plot]).

The sequence is found from the results' input attribute (beside the results file or in
the current folder) unless given with --sequence. See docs/video.md.
"""

from __future__ import annotations

import logging
from pathlib import Path

from irdetect.commands import DATASET_HELP, TRUTH_KINDS, find_sequence
from irdetect.errors import InputError

log = logging.getLogger(__name__)


def add_arguments(p):
    p.add_argument("results", help="results file of irdetect process (or of irdetect "
                   "initiate on scans: measurements, truth and tracks)")
    p.add_argument("-o", "--output", required=True,
                   help="figure file (.png, .jpg, .tif, .pdf or .svg)")
    p.add_argument("--sequence", help="the sequence the results were made from (default: "
                   "the input where it was read, else its name beside the results file)")
    p.add_argument("--dataset", help=DATASET_HELP)
    p.add_argument("--raw", action="store_true",
                   help="max projection of the raw frames (default: of the suppressed frames)")
    p.add_argument("--truth", nargs="?", const=True, default=None, metavar="FILE",
                   help="draw ground truth: alone, the sequence's /truth or its recording "
                   f"folder's truth.txt; or FILE ({TRUTH_KINDS})")
    p.add_argument("--scale", type=float, help="figure pixels per source pixel (default: "
                   "enough for 480 px width, at most 4)")
    p.add_argument("--gamma", type=float, default=1.0, help="display gamma (default 1)")
    p.add_argument("--roc", action="store_true",
                   help="draw the ROC instead: Pd against false detections per frame over "
                   "the detections' local SNR (the truth as for evaluate: the sequence's, "
                   "or --truth FILE; --gate)")
    p.add_argument("--gate", type=float, default=3.0,
                   help="--roc: match distance in px, as for evaluate (3)")
    p.add_argument("--force", action="store_true", help="overwrite an existing output")


def run(args) -> int:
    from irdetect.commands.video import resolve_truth
    from irdetect.io import check_output_path, open_sequence, read_results
    from irdetect.metrics.initiation import scan_tracks_of
    from irdetect.plot import require_matplotlib, plot_results, write_figure

    from irdetect.render import check_gamma

    if args.scale is not None and not 0.05 <= args.scale <= 16:
        raise InputError(f"--scale must lie in [0.05, 16], got {args.scale}")
    check_gamma(args.gamma)
    check_output_path(args.output, args.force, inputs=(args.results,))
    require_matplotlib()                             # the install hint before any work
    if not Path(args.results).exists():
        raise InputError("results file not found", args.results)
    if args.roc:
        return _roc(args)
    results = read_results(args.results)
    if scan_tracks_of(results, warn=False) is not None:    # irdetect initiate on scans
        from irdetect.plot_scans import plot_scan_results
        from matplotlib.figure import Figure

        image = plot_scan_results(results)
        fig = Figure(figsize=(image.shape[1] / 100, image.shape[0] / 100), dpi=100)
        fig.figimage(image[..., ::-1])                  # BGR -> RGB, pixel for pixel
        write_figure(args.output, fig, force=args.force, inputs=(args.results,))
        log.info("wrote %s (scans, %dx%d px)", args.output, image.shape[1], image.shape[0])
        return 0
    seq = find_sequence(results, args.sequence)
    if seq is None:
        log.warning("sequence %r not found beside %s; drawing over a dark background "
                    "(give it with --sequence)", results.attrs.get("input"), args.results)
        if args.truth is not None:
            raise InputError("--truth needs the sequence; give it with --sequence")
        fig = plot_results(results, None, scale=args.scale, gamma=args.gamma)
    else:
        with open_sequence(seq, args.dataset) as src:
            fig = plot_results(results, src, suppressed=not args.raw,
                                 truth=resolve_truth(args.truth, src), scale=args.scale,
                                 gamma=args.gamma, progress=args.progress)
    write_figure(args.output, fig, force=args.force, inputs=(args.results, seq))
    width, height = fig.canvas.get_width_height()
    log.info("wrote %s (%dx%d px)", args.output, width, height)
    return 0


def _roc(args) -> int:
    """``plot --roc``: the ROC of evaluate's detection section."""
    from irdetect.commands.evaluate import evaluate
    from irdetect.plot import plot_roc, write_figure

    truth = args.truth if isinstance(args.truth, str) else None
    scores = evaluate(args.results, truth, gate=args.gate).get("detection", {})
    if "roc" not in scores:
        raise InputError("holds no detections with a local SNR (snr) to rank: not the "
                         "results of irdetect process", args.results)
    name = Path(args.results).name
    fig = plot_roc({name: {**scores["roc"], "auc": scores["roc_auc"]}},
                   title=f"{name}: ROC (gate {args.gate:g} px)")
    write_figure(args.output, fig, force=args.force, inputs=(args.results,))
    log.info("wrote %s (ROC, area %.3f)", args.output, scores["roc_auc"])
    return 0
