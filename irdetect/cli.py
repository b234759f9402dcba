"""Command-line interface: argparse subcommands over the library.

Each subcommand lives in ``irdetect/commands/<name>.py`` with ``add_arguments(parser)``
and ``run(args) -> int``; this module only wires them. User errors (``InputError``), write
errors (disk full, no permission) and lack of memory end with exit code 2 and one line on
stderr, never a traceback (Python warnings raised on the way are then dropped, else shown
when the run ends); SIGINT and SIGTERM end with 130 and 143, leaving no output
(docs/reliability.md).
"""

from __future__ import annotations

import os

# OpenCV's and FFmpeg's own log lines stay off stderr unless -v (read when cv2 loads)
os.environ.setdefault("OPENCV_LOG_LEVEL", "SILENT")
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")

import argparse  # noqa: E402
import errno  # noqa: E402
import importlib  # noqa: E402
import logging  # noqa: E402
import math  # noqa: E402
import signal  # noqa: E402
import sys  # noqa: E402
import warnings  # noqa: E402

from irdetect import __version__  # noqa: E402
from irdetect.errors import InputError  # noqa: E402
from irdetect.io.atomic import on_signal, received  # noqa: E402

#: errors of writing a file that are the user's to fix, not irdetect's bugs
WRITE_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EACCES, errno.EPERM,
                errno.EROFS, errno.EIO, errno.ENAMETOOLONG}

#: (subcommand, module under irdetect.commands, one-line help)
COMMANDS = [
    ("process", "process", "detect dim point targets in a sequence and initiate their tracks"),
    ("simulate", "simulate", "write a synthetic IR sequence with ground truth"),
    ("convert", "convert", "convert a sequence (HDF5, image folder, TIFF stack, video, .npy, "
     ".mat) to HDF5"),
    ("info", "info", "say what a sequence, scans or results file holds"),
    ("evaluate", "evaluate", "score a results file against ground truth"),
    ("video", "video", "write an annotated video (.mp4, .avi or PNG frames) of a sequence and its results"),
    ("plot", "plot", "draw the tracks over the max projection and the Hough accumulator"),
    ("export", "export", "write results as CSV, MOTChallenge text or JSON for other tools"),
    ("track", "track", "track small targets frame by frame (FCM + adaptive PMHT)"),
    ("initiate", "initiate", "initiate tracks on radar-style scans (Hough + SC, fuzzy parallel Hough, M/N)"),
    ("simulate-scans", "simulate_scans", "write simulated radar-style scans (zhang2010, liang2015)"),
]


class _Parser(argparse.ArgumentParser):
    """argparse with its errors on one line (the usage is one ``--help`` away)."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="irdetect", description="Find dim point targets in infrared image sequences "
        "and initiate their tracks.")
    parser.add_argument("--version", action="version", version=f"irdetect {__version__}")
    common = _Parser(add_help=False)
    common.add_argument("-v", "--verbose", action="count", default=0, help="debug log output")
    common.add_argument("-q", "--quiet", action="store_true",
                        help="only errors; no progress bar")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True,
                                parser_class=_Parser)
    for name, module_name, help_text in COMMANDS:
        module = importlib.import_module(f"irdetect.commands.{module_name}")
        p = sub.add_parser(name, parents=[common], help=help_text,
                           description=(module.__doc__ or help_text).strip())
        module.add_arguments(p)
        p.set_defaults(run=module.run, parser=p)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the exit code (0 ok, 1 failure, 2 bad input, 130 / 143 on
    SIGINT / SIGTERM)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    _check_finite(args)
    level = logging.ERROR if args.quiet else logging.DEBUG if args.verbose else logging.INFO
    logging.basicConfig(level=level, format="irdetect: %(message)s", stream=sys.stderr)
    if args.verbose:            # the libraries' warnings too
        import cv2
        os.environ["OPENCV_FFMPEG_LOGLEVEL"] = "24"      # read when FFmpeg is first used
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_WARNING)
    args.progress = not args.quiet and sys.stderr.isatty()
    saved = _catch_signals()
    # the libraries' Python warnings (numpy's RuntimeWarning, ...) are held until the run
    # ends: shown after a run that succeeds or crashes, dropped when it ends in one line
    holding = warnings.catch_warnings(record=True)
    held = holding.__enter__()
    one_line = True
    try:
        code = int(args.run(args) or 0)
        if received:                   # a library swallowed the signal's exception
            raise KeyboardInterrupt
        one_line = False
        return code
    except InputError as exc:
        return _fail(args, str(exc))
    except KeyboardInterrupt:
        signum = received[0] if received else signal.SIGINT
        name = "terminated" if signum == signal.SIGTERM else "interrupted"
        print(f"irdetect {args.command}: {name}", file=sys.stderr)
        return 128 + int(signum)
    except BrokenPipeError:
        # the reader of stdout went away (`irdetect evaluate ... | head -1`): not an error
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except MemoryError:
        return _fail(args, "not enough memory for this input and configuration")
    except OSError as exc:
        if exc.errno not in WRITE_ERRNOS:
            one_line = False
            raise
        where = f"{exc.filename}: " if exc.filename else ""
        return _fail(args, f"{where}{exc.strerror}")
    except SystemExit:                 # an argparse error of the command: one line
        raise
    except BaseException:
        one_line = False               # a traceback: the warnings may tell why
        raise
    finally:
        holding.__exit__(None, None, None)
        if not one_line:
            for w in held:
                warnings.showwarning(w.message, w.category, w.filename, w.lineno)
        _restore_signals(saved)


def _check_finite(args) -> None:
    """Refuse NaN and inf in every numeric option (argparse's float() accepts them)."""
    sub = args.parser
    for action in sub._actions:
        value = getattr(args, action.dest, None)
        values = value if isinstance(value, (list, tuple)) else [value]
        if any(isinstance(v, float) and not math.isfinite(v) for v in values):
            sub.error(f"argument {'/'.join(action.option_strings) or action.dest}: "
                      f"must be a finite number, got {value}")


def _fail(args, message: str) -> int:
    print(f"irdetect {args.command}: error: {message}", file=sys.stderr)
    return 2


def _catch_signals() -> dict:
    """SIGINT and SIGTERM go to ``irdetect.io.atomic.on_signal``: ``KeyboardInterrupt``
    in the main thread, so every writer removes its temporary, and a flag, so nothing is
    committed even when a library swallowed the exception. Returns what to restore."""
    received.clear()
    saved = {"handlers": {}, "unraisable": sys.unraisablehook}
    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            saved["handlers"][sig] = signal.signal(sig, on_signal)
        except ValueError:     # not the main thread (a library caller): leave them
            pass

    def unraisable(info):
        # the signal's exception raised inside a weakref callback or __del__ cannot
        # propagate; the flag stops the run, so it is not worth a traceback
        if not (received and issubclass(info.exc_type, KeyboardInterrupt)):
            saved["unraisable"](info)

    sys.unraisablehook = unraisable
    return saved


def _restore_signals(saved: dict) -> None:
    for sig, old in saved["handlers"].items():
        signal.signal(sig, old)
    sys.unraisablehook = saved["unraisable"]
