"""One module per subcommand: ``add_arguments(parser)`` and ``run(args) -> int``."""

import dataclasses

#: what a sequence argument may be (``irdetect.io.open_sequence``), for the help texts
SEQUENCE_KINDS = "HDF5 file, folder of images, multi-page TIFF, video file, .npy or .mat"
#: the help of every ``--dataset``
DATASET_HELP = (
    "HDF5: dataset path (default /frames); MAT-file: variable (default: its only 3-D one)")
#: what ``--truth FILE`` may name (``irdetect.io.find_truth``)
TRUTH_KINDS = ("a sequence with /truth, a text file of 'x y' per frame, a recording folder, "
               "or a folder of target masks")
#: the help of every ``--polarity`` (``suppress.polarity``)
POLARITY_HELP = ("bright: targets brighter than their background (a white-hot recording, "
                 "the default); dark: darker (a black-hot recording, a cold target); "
                 "sets suppress.polarity")


def with_polarity(config, polarity):
    """``config`` with ``suppress.polarity`` set to ``polarity`` (None: unchanged)."""
    if polarity is None:
        return config
    return dataclasses.replace(config, suppress=dataclasses.replace(config.suppress,
                                                                    polarity=polarity))
