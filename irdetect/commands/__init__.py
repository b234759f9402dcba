"""One module per subcommand: ``add_arguments(parser)`` and ``run(args) -> int``."""

import dataclasses
from pathlib import Path

#: what a sequence argument may be (``irdetect.io.open_sequence``), for the help texts
SEQUENCE_KINDS = "HDF5 file, folder of images, multi-page TIFF, video file, .npy or .mat"
#: the help of every ``--dataset``
DATASET_HELP = (
    "HDF5: dataset path (default /frames); MAT-file: variable (default: its only 3-D one)")
#: what ``--truth FILE`` may name (``irdetect.io.find_truth``)
TRUTH_KINDS = ("a sequence with /truth, a text file of 'x y' per frame, a recording folder, "
               "or a folder of target masks")


def add_input_options(p) -> None:
    """``--polarity``, ``--exclude`` and ``--bin``: what the targets look like, where
    nothing is reported and the footage's pixel scale, shared by ``process`` and
    ``track`` (``with_input_options``)."""
    p.add_argument("--polarity", choices=["bright", "dark"],
                   help="bright: targets brighter than their background (a white-hot "
                   "recording, the default); dark: darker (a black-hot recording, a cold "
                   "target); sets suppress.polarity")
    p.add_argument("--exclude", action="append", metavar="X0,Y0,X1,Y1|MASK",
                   help="pixels where nothing is reported (a burned-in time stamp or "
                   "reticle): a rectangle in px (x = column; columns X0..X1-1, rows "
                   "Y0..Y1-1) or an image of the frames' size whose nonzero pixels are "
                   "excluded; repeatable, added to the configuration's exclude")
    p.add_argument("--bin", type=int, metavar="N",
                   help="average blocks of N x N pixels into one before everything else, "
                   "for footage sampled finer than its detail (an analog video digitised at "
                   "twice its sensor's resolution: hot pixels and point targets 2 px wide): "
                   "2; results stay in the input's pixels; sets suppress.bin (default 1)")


def with_input_options(config, args):
    """``config`` with ``--polarity`` (``suppress.polarity``), ``--bin``
    (``suppress.bin``) and ``--exclude`` (added to ``exclude``) of ``args`` applied."""
    for name in ("polarity", "bin"):
        if getattr(args, name) is not None:
            config = dataclasses.replace(config, suppress=dataclasses.replace(
                config.suppress, **{name: getattr(args, name)}))
    if args.exclude:
        config = dataclasses.replace(config, exclude=tuple(config.exclude) + tuple(args.exclude))
    return config


def find_sequence(results, given=None):
    """Path of the sequence: ``given``, else the results' input where it was read
    (``input_path``), beside the results file or in the current folder; None when not
    found."""
    if given:
        return given
    where = results.attrs.get("input_path")
    if where and Path(where).exists():
        return Path(where)
    name = results.attrs.get("input")
    if not name:
        return None
    for folder in (Path(results.path).resolve().parent, Path(".")):
        if (folder / name).exists():
            return folder / name
    return None


def flat_frames(path, dataset=None) -> str | None:
    """When the first, middle and last frames of the sequence at ``path`` each hold one
    value (a dataset of zeros, a dead recording), what to say about it after a run that
    found nothing; else None. Three frames are read, not the sequence."""
    import numpy as np

    from irdetect.io import open_sequence
    from irdetect.io.sources import HDF5_SUFFIXES, MAT_SUFFIXES

    with open_sequence(path, dataset=dataset) as src:
        picks = sorted({0, len(src) // 2, len(src) - 1})
        frames = [np.asarray(src[t:t + 1][0]) for t in picks]
    if any(np.ptp(f) > 0 for f in frames):
        return None
    values = sorted({f.flat[0].item() for f in frames})
    where = (" (another dataset of the file? --dataset names it)"
             if Path(path).suffix.lower() in HDF5_SUFFIXES | MAT_SUFFIXES else "")
    return (f"frames {', '.join(map(str, picks))} each hold a single value "
            f"({', '.join(f'{v:g}' for v in values)}): nothing in them to detect{where}")
