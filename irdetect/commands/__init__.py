"""One module per subcommand: ``add_arguments(parser)`` and ``run(args) -> int``."""

#: what a sequence argument may be (``irdetect.io.open_sequence``), for the help texts
SEQUENCE_KINDS = "HDF5 file, folder of images, multi-page TIFF, video file, .npy or .mat"
#: the help of every ``--dataset``
DATASET_HELP = (
    "HDF5: dataset path (default /frames); MAT-file: variable (default: its only 3-D one)")
#: what ``--truth FILE`` may name (``irdetect.io.find_truth``)
TRUTH_KINDS = ("a sequence with /truth, a text file of 'x y' per frame, a recording folder, "
               "or a folder of target masks")
