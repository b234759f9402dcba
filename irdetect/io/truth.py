"""Where ground truth comes from: one rule for every command that takes ``--truth``.

``find_truth`` looks, in order, at a file given by the user, else the sequence itself:
a sequence file's ``/truth``, or the ``truth.txt`` of a recording folder (the folder of
frames holds it, or sits beside it: ``shared/data/real/NAME/{frames/, truth.txt}``). When
nothing is found every command says the same thing (``NO_TRUTH``). The user may also name
a folder of target masks, one binary image per frame (the IRSTD datasets' annotation):
each mask's 8-connected regions are targets at their centroids (``read_mask_folder``).
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
            "frame, a recording folder, or a folder of target masks)")

ANNOTATION_SUFFIXES = (".txt", ".csv")
#: a mask region of one frame continues a target of the frame before within this many px
#: (nearest first, one to one); farther, it starts a new target
MASK_LINK_PX = 20.0


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
        annotation file (one ``x y`` line per frame, x = column, y = row), a recording
        folder, or a folder of target masks (``read_mask_folder``). None: look at
        ``sequence``.
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
                return Truth(read_mask_folder(p, n_frames), os.fspath(p))
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


def read_mask_folder(folder: str | os.PathLike, n_frames: int | None = None) -> np.ndarray:
    """Point truth from a folder of target masks, one binary image per frame in natural
    order of the names (the annotation of IRSTD datasets: a target's pixels non-zero).

    Each mask's 8-connected regions are targets at their centroids (x = column, y = row,
    px, the mean of their pixels' centres). A region continues the target of the frame
    before whose centroid lies nearest, one to one, within ``MASK_LINK_PX`` px; else it
    starts a new target. An empty mask is a frame without a target.

    Parameters
    ----------
    folder : str or os.PathLike
        The masks (PNG, TIFF, BMP, ...; ``irdetect.io.sources.folder_images``).
    n_frames : int, optional
        Frames of the sequence: the folder must hold this many masks.

    Returns
    -------
    structured ndarray
        ``irdetect.tables.TRUTH`` rows (amplitude NaN), by frame, then target.

    Raises
    ------
    InputError
        No images, another count than ``n_frames``, an image of more than two values (not
        a mask: frames given by mistake), or masks of different sizes.
    """
    import cv2
    from scipy.optimize import linear_sum_assignment

    from irdetect import tables
    from irdetect.io.sources import folder_images

    files = folder_images(folder)
    if not files:
        raise InputError(NO_TRUTH, folder)
    if n_frames is not None and len(files) != n_frames:
        raise InputError(f"{len(files)} masks for {n_frames} frames", folder)
    rows, last, last_ids, next_id, shape = [], np.zeros((0, 2)), np.zeros(0, int), 0, None
    for f, file in enumerate(files):          # a loop over frames (one image each)
        image = cv2.imread(str(file), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_ANYDEPTH)
        if image is None:
            raise InputError("cannot read this mask", file)
        if shape is not None and image.shape != shape:
            raise InputError(f"masks of different sizes: {file.name} is {image.shape[1]}x"
                             f"{image.shape[0]}, the first {shape[1]}x{shape[0]}", folder)
        shape = image.shape
        if len(np.unique(image)) > 2:
            if f == 0:              # frames, not masks (a folder of frames without truth)
                raise InputError(f"{NO_TRUTH} ({file.name} holds more than two values: "
                                 "not a target mask)", folder)
            raise InputError(f"{file.name} is not a target mask (more than two values)",
                             folder)
        centres = cv2.connectedComponentsWithStats((image > 0).astype(np.uint8),
                                                   connectivity=8)[3]
        xy = centres[1:]                                   # label 0 is the background
        ids = np.full(len(xy), -1)
        if len(xy) and len(last):
            d = np.hypot(xy[:, None, 0] - last[None, :, 0], xy[:, None, 1] - last[None, :, 1])
            r, c = linear_sum_assignment(np.where(d <= MASK_LINK_PX, d, 1e9))
            ok = d[r, c] <= MASK_LINK_PX
            ids[r[ok]] = last_ids[c[ok]]
        new = ids < 0
        ids[new] = np.arange(next_id, next_id + new.sum())
        next_id += int(new.sum())
        rows.append(np.column_stack([np.full(len(xy), f), ids, xy]))
        last, last_ids = xy, ids
    rows = np.concatenate(rows)                            # (frame, target, x, y)
    out = tables.from_columns(tables.TRUTH, frame=rows[:, 0].astype(np.int64),
                              target=rows[:, 1].astype(np.int64), x=rows[:, 2], y=rows[:, 3])
    return out[np.lexsort((out["target"], out["frame"]))]
