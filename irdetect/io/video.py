"""Write frames for people to watch: an .mp4 / .avi video or a folder of PNG frames.

The output kind follows the path: ``.mp4`` (MPEG-4 part 2, fourcc ``mp4v``), ``.avi``
(Motion-JPEG, fourcc ``MJPG``), or a path without a suffix (or an existing folder): a
folder of PNG frames ``frame_000000.png``, ``frame_000001.png``, ... named by the index of
the source frame. Like every irdetect output the result is written under a temporary name
beside the target and renamed into place only when all frames are written; a failed or
interrupted run leaves nothing at the output path, and an existing output is replaced
only with ``force=True``.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from irdetect.errors import InputError
from irdetect.io.atomic import atomic_output, check_output_path, check_output_place, leave

#: suffix -> fourcc of the OpenCV video writer
CODECS = {".mp4": "mp4v", ".avi": "MJPG"}
#: name pattern of the frames of a PNG-folder output
PNG_PATTERN = "frame_{:06d}.png"


def output_kind(path: str | os.PathLike) -> str:
    """``"mp4"``, ``"avi"`` or ``"png"`` (a folder of frames) for an output path.

    Raises
    ------
    InputError
        A suffix other than .mp4 / .avi on a path that is not an existing folder.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix in CODECS:
        return suffix[1:]
    if p.is_dir() or suffix == "" or os.fspath(path).endswith(("/", os.sep)):
        return "png"
    raise InputError(f"unknown video output type {p.suffix!r} (use .mp4, .avi, or a folder "
                     "name without a suffix for PNG frames)", path)


def check_video_path(path: str | os.PathLike, force: bool = False,
                     inputs=()) -> tuple[Path, str]:
    """Check that a video / PNG-folder output can be written; returns (path, kind).

    ``inputs`` are the run's input files and folders: the output may be none of them.

    Raises
    ------
    InputError
        Unknown suffix, missing or read-only parent folder, an existing output without
        ``force``, a file where a folder is wanted (or the reverse), or an existing folder
        that holds anything other than PNG frames (never deleted, even with ``force``).
    """
    kind = output_kind(path)
    p = Path(os.fspath(path).rstrip("/" + os.sep) or ".")
    check_output_place(p, inputs)
    if kind == "png":
        if p.exists() and not p.is_dir():
            raise InputError("a PNG-frame output must be a folder, but this is a file", path)
        if p.is_dir() and any(p.iterdir()):
            if not force:
                raise InputError("output folder exists and is not empty; use --force to "
                                 "replace its frames", path)
            others = [q.name for q in p.iterdir()
                      if not (q.is_file() and q.suffix.lower() == ".png")]
            if others:
                raise InputError(f"output folder holds files other than PNG frames "
                                 f"({others[0]!r}, ...); refusing to replace it", path)
    else:
        check_output_path(p, force)
    return p, kind


class VideoWriter:
    """Write BGR frames atomically to a video file or a folder of PNG frames.

    Parameters
    ----------
    path : str or os.PathLike
        ``*.mp4``, ``*.avi`` or a folder (see ``output_kind``).
    fps : float
        Frames per second of the video (ignored for PNG frames).
    force : bool
        Replace an existing output.

    Notes
    -----
    MPEG-4 and Motion-JPEG need even frame sizes: a frame of odd width or height is
    padded with one black column / row on the right / bottom (PNG frames are written
    as given). Every frame must have the size of the first.

    Examples
    --------
    >>> with VideoWriter("out.mp4", fps=25) as out:             # doctest: +SKIP
    ...     out.write(np.zeros((240, 320, 3), np.uint8))
    """

    def __init__(self, path: str | os.PathLike, *, fps: float = 25.0, force: bool = False,
                 inputs=()):
        if not (np.isfinite(fps) and fps > 0):
            raise ValueError(f"fps must be a positive number, got {fps}")
        self.path, self.kind = check_video_path(path, force, inputs)
        self.fps = float(fps)
        self.count = 0
        self._output = atomic_output(self.path, force=force, inputs=inputs,
                                     suffix=f".{self.kind}", folder=self.kind == "png")
        self._tmp: str | None = None
        self._writer = None
        self._size: tuple[int, int] | None = None     # (H, W) of the first frame

    def __enter__(self) -> "VideoWriter":
        self._tmp = self._output.__enter__()
        return self

    def write(self, frame: np.ndarray, index: int | None = None) -> None:
        """Append one frame.

        Parameters
        ----------
        frame : ndarray of shape (H, W, 3) uint8 (BGR) or (H, W) uint8 (grey)
        index : int, optional
            Source frame number, used in the PNG file name (default: frames written so far).
        """
        if self._tmp is None:
            raise RuntimeError("use VideoWriter as a context manager")
        frame = np.asarray(frame)
        if frame.dtype != np.uint8 or frame.ndim not in (2, 3):
            raise ValueError(f"frame must be uint8 (H, W) or (H, W, 3), got {frame.dtype} "
                             f"{frame.shape}")
        if frame.ndim == 2:
            frame = cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
        if self._size is None:
            self._size = frame.shape[:2]
            if self.kind != "png":
                self._open_video()
        elif frame.shape[:2] != self._size:
            raise ValueError(f"frame {self.count} is {frame.shape[1]}x{frame.shape[0]}, the "
                             f"first was {self._size[1]}x{self._size[0]}")
        if self.kind == "png":
            name = os.path.join(self._tmp, PNG_PATTERN.format(self.count if index is None
                                                              else int(index)))
            if not cv2.imwrite(name, frame):
                raise InputError("cannot write PNG frame", name)
        else:
            h, w = frame.shape[:2]
            if h % 2 or w % 2:
                frame = cv2.copyMakeBorder(frame, 0, h % 2, 0, w % 2, cv2.BORDER_CONSTANT,
                                           value=(0, 0, 0))
            self._writer.write(np.ascontiguousarray(frame))
        self.count += 1

    def _open_video(self) -> None:
        h, w = self._size
        size = (w + w % 2, h + h % 2)
        writer = cv2.VideoWriter(self._tmp, cv2.VideoWriter_fourcc(*CODECS["." + self.kind]),
                                 self.fps, size)
        if not writer.isOpened():
            raise InputError(f"OpenCV cannot write {self.kind} video "
                             f"(codec {CODECS['.' + self.kind]})", self.path)
        self._writer = writer

    def __exit__(self, exc_type, exc, tb):
        return leave(self._output, (exc_type, exc, tb), self._close)

    def _close(self, ok: bool) -> None:
        if self._writer is not None:
            self._writer.release()
        if ok and self.count == 0:
            raise InputError("no frames to write", self.path)
        if ok and self.kind != "png" and os.path.getsize(self._tmp) == 0:
            raise InputError("the video encoder wrote nothing (disk full?)", self.path)
