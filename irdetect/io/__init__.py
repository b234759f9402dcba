"""Reading sequences and writing results: one FrameSource for every input kind, atomic HDF5."""

from irdetect.io.results import (AtomicH5, Results, ResultsWriter, check_output_path,
                                 read_point_annotations, read_results, write_sequence)
from irdetect.io.sources import FrameSource, open_sequence

__all__ = ["AtomicH5", "FrameSource", "Results", "ResultsWriter", "check_output_path",
           "open_sequence", "read_point_annotations", "read_results", "write_sequence"]
