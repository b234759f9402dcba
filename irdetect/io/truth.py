"""Where ground truth comes from: one rule for every command that takes ``--truth``.

``find_truth`` looks, in order, at a file given by the user, else the sequence itself:
a sequence file's ``/truth``, or the ``truth.txt`` of a recording folder (the folder of
frames holds it, or sits beside it: ``shared/data/real/NAME/{frames/, truth.txt}``). When
nothing is found every command says the same thing (``NO_TRUTH``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from irdetect.errors import InputError

#: the message when no truth is found, whichever command looked
NO_TRUTH = ("no ground truth: no /truth in the sequence and no truth.txt in its folder or "
            "beside it; give --truth FILE (a sequence with /truth, a text file of 'x y' per "
            "frame, or a recording folder)")

ANNOTATION_SUFFIXES = (".txt", ".csv")


@dataclass
class Truth:
    """Ground truth found for a sequence.

    Attributes
    ----------
    table : structured ndarray
        ``irdetect.tables.TRUTH`` rows (x = column, y = row, px; frames from 0).
    path : str
        The file it was read from (a sequence file or an annotation file).
    shape : tuple of int or None
        (T, H, W) of the sequence it came with; None for an annotation file.
    """

    table: np.ndarray
    path: str
    shape: tuple[int, int, int] | None = None


def recording_truth(folder: str | os.PathLike) -> Path | None:
    """The ``truth.txt`` of a recording folder: in ``folder`` or in its parent (``folder``
    being the ``frames/`` subfolder); None when there is none or ``folder`` is a file."""
    folder = Path(folder)
    if not folder.is_dir():
        return None
    for candidate in (folder / "truth.txt", folder.parent / "truth.txt"):
        if candidate.is_file():
            return candidate
    return None


def find_truth(given=None, *, sequence=None, n_frames: int | None = None) -> Truth:
    """Ground truth by the one rule of ``--truth``.

    Parameters
    ----------
    given : str, os.PathLike or None
        What the user named with ``--truth FILE``: a sequence file with ``/truth``, a point
        annotation file (one ``x y`` line per frame, x = column, y = row) or a recording
        folder. None: look at ``sequence``.
    sequence : str, os.PathLike, irdetect.io.FrameSource or None
        The sequence the results were made from (a path, or an open source): its
        ``/truth``, else its recording folder's ``truth.txt``.
    n_frames : int, optional
        Frames of the sequence; an annotation file must have this many lines.

    Returns
    -------
    Truth

    Raises
    ------
    InputError
        Nothing given and nothing found (``NO_TRUTH``), or an unreadable file.
    """
    from irdetect.io.results import read_point_annotations
    from irdetect.io.sources import FrameSource, open_sequence

    if given is not None:
        p = Path(given)
        if p.is_dir():
            found = recording_truth(p)
            if found is None:
                raise InputError(NO_TRUTH, p)
            p = found
        if p.suffix.lower() in ANNOTATION_SUFFIXES:
            return Truth(read_point_annotations(p, n_frames), os.fspath(p))
        with open_sequence(p) as src:
            if src.truth is None:
                raise InputError(NO_TRUTH, p)
            return Truth(src.truth, os.fspath(p), tuple(src.shape))
    if sequence is None:
        raise InputError(NO_TRUTH)
    if isinstance(sequence, FrameSource):
        return _truth_of(sequence)
    with open_sequence(sequence) as src:
        return _truth_of(src)


def _truth_of(src) -> Truth:
    from irdetect.io.results import read_point_annotations

    if src.truth is not None:
        return Truth(src.truth, src.path, tuple(src.shape))
    found = recording_truth(src.path)
    if found is None:
        raise InputError(NO_TRUTH, src.path)
    return Truth(read_point_annotations(found, len(src)), os.fspath(found), tuple(src.shape))
