"""Reading sequences and writing results: one FrameSource for every input kind, atomic HDF5."""

from irdetect.io.atomic import atomic_output, check_output_path
from irdetect.io.results import (AtomicH5, Results, ResultsWriter, read_point_annotations,
                                 read_results, write_sequence)
from irdetect.io.sources import FrameSource, open_sequence
from irdetect.io.truth import NO_TRUTH, Truth, find_truth

__all__ = ["AtomicH5", "FrameSource", "NO_TRUTH", "Results", "ResultsWriter", "Truth",
           "atomic_output", "check_output_path", "find_truth", "open_sequence",
           "read_point_annotations", "read_results", "write_sequence"]
