"""Command-line interface: argparse subcommands over the library.

Each subcommand lives in ``irdetect/commands/<name>.py`` with ``add_arguments(parser)``
and ``run(args) -> int``; this module only wires them. User errors (``InputError``)
end with exit code 2 and one line on stderr, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

from irdetect import __version__
from irdetect.errors import InputError

#: (subcommand, module under irdetect.commands, one-line help)
COMMANDS = [
    ("process", "process", "detect dim point targets in a sequence and initiate their tracks"),
    ("simulate", "simulate", "write a synthetic IR sequence with ground truth"),
    ("convert", "convert", "convert a sequence (HDF5, image folder, TIFF stack, video, .npy) to HDF5"),
    ("info", "info", "say what a sequence, scans or results file holds"),
    ("evaluate", "evaluate", "score a results file against ground truth"),
    ("video", "video", "write an annotated video (.mp4, .avi or PNG frames) of a sequence and its results"),
    ("plot", "plot", "draw the tracks over the max projection and the Hough accumulator"),
    ("export", "export", "write results as CSV, MOTChallenge text or JSON for other tools"),
    ("track", "track", "track small targets frame by frame (FCM + adaptive PMHT)"),
    ("initiate", "initiate", "initiate tracks on radar-style scans (Hough + SC, fuzzy parallel Hough, M/N)"),
    ("simulate-scans", "simulate_scans", "write simulated radar-style scans (zhang2010, liang2015)"),
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="irdetect", description="Find dim point targets in infrared image sequences "
        "and initiate their tracks.")
    parser.add_argument("--version", action="version", version=f"irdetect {__version__}")
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("-v", "--verbose", action="count", default=0, help="debug log output")
    common.add_argument("-q", "--quiet", action="store_true",
                        help="only errors; no progress bar")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, module_name, help_text in COMMANDS:
        module = importlib.import_module(f"irdetect.commands.{module_name}")
        p = sub.add_parser(name, parents=[common], help=help_text,
                           description=(module.__doc__ or help_text).strip())
        module.add_arguments(p)
        p.set_defaults(run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the exit code (0 ok, 1 failure, 2 bad input)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.ERROR if args.quiet else logging.DEBUG if args.verbose else logging.INFO
    logging.basicConfig(level=level, format="irdetect: %(message)s", stream=sys.stderr)
    args.progress = not args.quiet and sys.stderr.isatty()
    try:
        return int(args.run(args) or 0)
    except InputError as exc:
        print(f"irdetect {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"irdetect {args.command}: interrupted", file=sys.stderr)
        return 130
