"""Sequence readers behind one interface, read lazily so long sequences stream.

``open_sequence(path)`` picks the reader from the path: an HDF5 file, a folder of images
(PNG / TIFF / BMP, 8 or 16 bit, natural sort), a multi-page TIFF or OME-TIFF stack
(``tifffile``, the ``tiff`` extra), a video file (OpenCV), a ``.npy`` file
(memory-mapped) or a MATLAB MAT-file (an H x W x T variable). Every reader is a
:class:`FrameSource`: frames of shape (H, W), sliced as ``src[a:b]`` -> ndarray of shape
(b - a, H, W) in the file's dtype.
"""

from __future__ import annotations

import logging
import os
import re
import zlib
from contextlib import contextmanager
from pathlib import Path

import cv2
import h5py
import numpy as np

from irdetect import tables
from irdetect.errors import InputError, check_input_file

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = {".png", ".tif", ".tiff", ".bmp", ".jpg", ".jpeg", ".pgm"}
VIDEO_SUFFIXES = {".mp4", ".avi", ".mov", ".mkv", ".mpg", ".mpeg", ".wmv", ".m4v"}
HDF5_SUFFIXES = {".h5", ".hdf5", ".hdf", ".he5"}
TIFF_SUFFIXES = {".tif", ".tiff"}
MAT_SUFFIXES = {".mat"}
#: sequence files that are not HDF5 (a single image is none: ``open_sequence``)
OTHER_SEQUENCE_SUFFIXES = TIFF_SUFFIXES | VIDEO_SUFFIXES | MAT_SUFFIXES | {".npy"}
#: the text a MATLAB MAT-file of version 7.3 (an HDF5 file) starts with
MATLAB_HDF5 = b"MATLAB 7.3 MAT-file"
#: MATLAB classes of numeric arrays (the ``MATLAB_class`` attribute of a v7.3 variable)
MATLAB_NUMERIC = {"double", "single", "int8", "uint8", "int16", "uint16", "int32", "uint32",
                  "int64", "uint64"}
SUPPORTED_DTYPES = (np.uint8, np.uint16, np.int16, np.int32, np.float32, np.float64)


class FrameSource:
    """A sequence of (H, W) frames read on demand.

    Attributes
    ----------
    path : str
        The input path.
    shape : tuple of int
        (T, H, W).
    dtype : numpy.dtype
        The pixel type of the frames as read: the stored one, widened where the stages do
        not take it (``working_dtype``: other integers to float64, float16 to float32).
    stored_dtype : numpy.dtype
        The pixel type in the file.
    frame_rate : float or None
        Frames per second, when the file says.
    codec : str or None
        A video's codec, its FOURCC tag as OpenCV reports it (lower case: "h264", "fmp4"
        for MPEG-4 part 2, "ffv1"); None for other inputs.
    truth : structured ndarray or None
        Ground truth (``irdetect.tables.TRUTH``) stored with the sequence, if any.
    """

    path: str
    shape: tuple[int, int, int]
    dtype: np.dtype
    stored_dtype: np.dtype
    frame_rate: float | None = None
    codec: str | None = None
    truth: np.ndarray | None = None

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, index):
        if isinstance(index, (int, np.integer)):
            i = int(index) + (len(self) if index < 0 else 0)
            if not 0 <= i < len(self):
                raise IndexError(f"frame {index} out of range for {len(self)} frames")
            return self._typed(i, i + 1)[0]
        if isinstance(index, slice):
            start, stop, step = index.indices(len(self))
            if step != 1:
                return self._typed(start, stop)[::step]
            return self._typed(start, max(start, stop))
        raise TypeError("index a FrameSource with an int or a slice")

    def _set_dtype(self, shape, stored) -> None:
        """Refuse a stack of the wrong shape or pixel type (``InputError``); set ``dtype``
        (``working_dtype``) and ``stored_dtype``."""
        path = self.path
        if len(shape) != 3:
            raise InputError(f"frames must be 3-D (T, H, W), got {len(shape)}-D shape {shape}",
                             path)
        if shape[0] == 0:
            raise InputError("the sequence has 0 frames", path)
        if shape[1] < 1 or shape[2] < 1:
            raise InputError(f"frames of size {shape[1]}x{shape[2]} are empty", path)
        working = working_dtype(stored)
        if working is None:
            raise InputError(f"unsupported pixel type {np.dtype(stored)} (irdetect reads "
                             "integer and floating-point pixels)", path)
        self.dtype, self.stored_dtype = working, np.dtype(stored)

    def _typed(self, start: int, stop: int) -> np.ndarray:
        """Frames [start, stop) in the source's ``dtype`` (the stored type widened where
        the stages do not take it: ``working_dtype``)."""
        frames = self._read(start, stop)
        return frames if frames.dtype == self.dtype else frames.astype(self.dtype)

    def _read(self, start: int, stop: int) -> np.ndarray:
        raise NotImplementedError

    #: frames per read that the storage favours (HDF5: the chunk length along time)
    block_frames: int = 1

    def read_into(self, start: int, stop: int, out: np.ndarray) -> None:
        """Read frames [start, stop) into ``out`` (shape (stop - start, H, W), the source's
        dtype) without allocating; for streaming readers that reuse one buffer."""
        out[...] = self._read(start, stop)

    def windows(self, length: int, step: int | None = None):
        """Yield ``(start, frames)`` over consecutive windows of ``length`` frames.

        The last window may be shorter. Only one window is held in memory at a time.
        """
        step = length if step is None else step
        if length < 1 or step < 1:
            raise ValueError(f"window length and step must be >= 1, got {length}, {step}")
        for start in range(0, len(self), step):
            yield start, self[start:start + length]

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.path!r}, shape={self.shape}, dtype={self.dtype})"


class FrameView:
    """Frames computed from another sequence's on demand (``irdetect.binning.Binned``,
    ``irdetect.repeats.NewFrames``): ``len()``, ``.shape``, ``.dtype``, ``.path``,
    ``.block_frames`` and slicing ``[a:b]`` (step 1) or ``[i]``, as a FrameSource reads.

    Parameters
    ----------
    frames : ndarray of shape (T, H, W) or FrameSource
        Anything with ``len()``, ``.shape`` and slicing ``frames[a:b]`` -> (b - a, H, W).
    shape : tuple of int
        The view's (T', H', W').
    dtype : numpy.dtype
        The view's pixel type.
    """

    def __init__(self, frames, shape, dtype):
        self.frames, self.shape, self.dtype = frames, tuple(shape), np.dtype(dtype)
        self.block_frames = int(getattr(frames, "block_frames", 1))
        self.path = getattr(frames, "path", None)

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, index) -> np.ndarray:
        if isinstance(index, (int, np.integer)):
            i = int(index) + (len(self) if index < 0 else 0)
            return self[i:i + 1][0]
        a, b, step = index.indices(len(self))
        if step != 1:
            raise ValueError(f"{type(self).__name__} takes slices of step 1")
        return self._read(a, max(a, b))

    def _read(self, start: int, stop: int) -> np.ndarray:
        """The view's frames [start, stop) (start <= stop)."""
        raise NotImplementedError

    def _raw(self, start: int, stop: int) -> np.ndarray:
        """The underlying frames [start, stop); a file's checked finite (docs/format.md)."""
        raw = np.asarray(self.frames[start:stop])
        if isinstance(self.frames, FrameSource):
            check_values(raw, start, self.path)
        return raw


#: the largest magnitude the stages compute with (they work in float32)
FLOAT32_MAX = float(np.finfo(np.float32).max)


def check_values(frames: np.ndarray, start: int, path, *, limit: float | None = FLOAT32_MAX
                 ) -> None:
    """Refuse floating-point frames holding NaN or inf, or values beyond ``limit``.

    Frames of a file must be finite (docs/format.md). The test is one pass with numpy's
    floating-point warnings off (``PYTHONWARNINGS=default`` must not print them before the
    error line): for float32 frames a float64 sum, which NaN or inf anywhere makes
    non-finite and no finite float32 value overflows; for float64 frames their min and
    max, which must lie within +-``limit`` (the stages cast to float32: a larger value
    would overflow there).

    Parameters
    ----------
    frames : ndarray of shape (n, H, W)
        Frames ``start .. start + n - 1``; integer frames always pass.
    start : int
        The first frame's index, for the message.
    path : str or os.PathLike or None
        The file, named in the message.
    limit : float or None
        Largest magnitude allowed (float32's by default); None: only NaN and inf fail.

    Raises
    ------
    InputError
        "frame A holds NaN or inf values (...)" (which frames, how many pixels, the first
        one), or values beyond the limit.
    """
    if frames.dtype.kind != "f" or frames.size == 0:
        return
    with np.errstate(all="ignore"):
        if limit is None or frames.dtype.itemsize <= 4:
            ok = bool(np.isfinite(np.sum(frames, dtype=np.float64)))
        else:                   # NaN fails the comparisons
            ok = bool(-limit <= np.min(frames) and np.max(frames) <= limit)
        if ok:
            return
        where = f"frames {start}..{start + len(frames) - 1}"
        bad = ~np.isfinite(frames)
        if bad.any():
            raise InputError(_nonfinite_message(bad, start), path)
    if limit is None:           # finite float64 values whose sum overflowed
        return
    raise InputError(f"{where} hold values beyond +-{limit:.3g} (float32's range, in which "
                     "irdetect computes)", path)


def _nonfinite_message(bad: np.ndarray, start: int) -> str:
    """Where the NaN or inf pixels ``bad`` (n, H, W) of frames ``start ..`` lie: the
    frames (the first three named), the pixel count and the first pixel (x = column,
    y = row)."""
    counts = bad.reshape(len(bad), -1).sum(axis=1)
    idx = np.flatnonzero(counts)
    first = start + int(idx[0])
    y, x = np.argwhere(bad[idx[0]])[0]
    names = ", ".join(str(start + int(i)) for i in idx[:3])
    if len(idx) > 3:
        names += f" and {len(idx) - 3} more"
    if len(idx) == 1 and counts[idx[0]] == bad[0].size:
        where = "the whole frame"
    else:
        at = f"at x {int(x)}, y {int(y)}" if counts.sum() == 1 else (
            f"the first at x {int(x)}, y {int(y)} of frame {first}")
        where = f"{int(counts.sum())} px in frames {start}..{start + len(bad) - 1}, {at}"
    verb = "frame" if len(idx) == 1 else "frames"
    return (f"{verb} {names} {'holds' if len(idx) == 1 else 'hold'} NaN or inf values "
            f"({where}; irdetect needs finite pixel values)")


def working_dtype(dtype) -> np.dtype | None:
    """The pixel type frames of ``dtype`` are read as: the stored one when the stages take
    it (``SUPPORTED_DTYPES``), float64 for other integers (int8, uint32, int64, uint64:
    exact up to 2**53), float32 for float16; None for others (bool, complex, text)."""
    dtype = np.dtype(dtype)
    if dtype in [np.dtype(d) for d in SUPPORTED_DTYPES]:
        return dtype
    if dtype.kind in "iu":
        return np.dtype(np.float64)
    if dtype.kind == "f" and dtype.itemsize < 4:
        return np.dtype(np.float32)
    return None


class HDF5Source(FrameSource):
    """Frames from a 3-D dataset of an HDF5 file (``/frames`` by default).

    With ``dataset=None`` the reader takes ``/frames``, else the file's only 3-D dataset.
    ``/truth`` and the root attribute ``frame_rate`` are read when present.
    """

    def __init__(self, path, dataset: str | None = None):
        self.path = os.fspath(path)
        try:
            self._file = h5py.File(self.path, "r")
        except FileNotFoundError:
            raise InputError("file not found", path) from None
        except OSError as exc:
            raise InputError(f"not a readable HDF5 file ({_short(exc)})", path) from None
        try:
            self._dset = self._find_dataset(dataset)
            self._set_dtype(self._dset.shape, self._dset.dtype)
            self.shape = tuple(int(n) for n in self._dset.shape)
            self.frame_rate = _frame_rate(self._file.attrs.get("frame_rate"), self.path)
            self.truth = _read_truth(self._file, self.path)
            self.block_frames = self._block_frames()
            self._dset[0, :1, :1]  # a truncated file fails here, not mid-run
        except InputError:
            self._file.close()
            raise
        except (OSError, KeyError, ValueError) as exc:
            self._file.close()
            raise InputError(f"corrupt or truncated HDF5 file ({_short(exc)})", path) from None

    #: plain (unfiltered) chunks: read ahead at most this many bytes
    PLAIN_BLOCK_BYTES = 8 << 20

    def _block_frames(self) -> int:
        """Filtered (compressed) chunks are best read whole (a chunk read in pieces is
        decompressed once per piece); plain chunks can be read in any slice, so a read
        of a few MB is enough (a 64-frame chunk of 640x512 uint16 frames is 42 MB of
        read-ahead buffer otherwise)."""
        chunks = self._dset.chunks
        if not chunks:
            return 1
        if self._dset.id.get_create_plist().get_nfilters():
            return int(chunks[0])
        frame_bytes = self.shape[1] * self.shape[2] * self.dtype.itemsize
        return max(1, min(int(chunks[0]), self.PLAIN_BLOCK_BYTES // frame_bytes))

    def _find_dataset(self, name):
        if name is not None:
            obj = self._file.get(name)
            if not isinstance(obj, h5py.Dataset):
                raise InputError(f"no dataset {name!r} in the file", self.path)
            return obj
        if isinstance(self._file.get("frames"), h5py.Dataset):
            return self._file["frames"]
        found = []
        self._file.visititems(lambda n, o: found.append(n)
                              if isinstance(o, h5py.Dataset) and o.ndim == 3 else None)
        if not found:
            raise InputError("no 3-D dataset (T, H, W) in the file; expected /frames", self.path)
        if len(found) > 1:
            raise InputError(f"several 3-D datasets ({', '.join('/' + f for f in found)}); "
                             "choose one with --dataset", self.path)
        return self._file[found[0]]

    def _read(self, start, stop):
        try:
            return self._dset[start:stop]
        except (OSError, ValueError) as exc:
            raise InputError(f"corrupt or truncated HDF5 file ({_short(exc)})", self.path) from None

    def read_into(self, start, stop, out):
        if stop <= start:
            return
        try:
            self._dset.read_direct(out, np.s_[start:stop], np.s_[0:stop - start])
        except (OSError, ValueError) as exc:
            raise InputError(f"corrupt or truncated HDF5 file ({_short(exc)})", self.path) from None

    def close(self):
        if self._file.id.valid:
            self._file.close()


class MatlabHDF5Source(HDF5Source):
    """Frames of a MATLAB MAT-file of version 7.3 (``save -v7.3``, an HDF5 file).

    The sequence is a 3-D numeric variable of H x W x T, frame k being ``seq(:,:,k)``
    (MATLAB's image stacks: ``cat(3, ...)``, ``implay``). HDF5 holds MATLAB's
    column-major array with its axes reversed, (T, W, H), so each frame is read
    transposed. The variable is the one named by ``dataset``, else the file's only 3-D
    numeric variable.
    """

    def __init__(self, path, dataset: str | None = None):
        super().__init__(path, dataset)
        t, w, h = self.shape
        self.shape = (t, h, w)

    def _find_dataset(self, name):
        if name is not None:
            return super()._find_dataset(name)
        found = [k for k, obj in self._file.items()
                 if isinstance(obj, h5py.Dataset) and obj.ndim == 3
                 and _text(obj.attrs.get("MATLAB_class")) in MATLAB_NUMERIC]
        return self._file[_only_variable(found, self.path)]

    def _read(self, start, stop):
        return np.ascontiguousarray(super()._read(start, stop).transpose(0, 2, 1))

    def read_into(self, start, stop, out):
        if stop > start:
            out[...] = super()._read(start, stop).transpose(0, 2, 1)


class MatSource(FrameSource):
    """Frames of a MATLAB MAT-file of version 7 or older (``scipy.io.loadmat``, read
    whole: such a file holds at most 2 GB per variable): a 3-D numeric variable of
    H x W x T, frame k being ``seq(:,:,k)``; the one named by ``dataset``, else the file's
    only one."""

    def __init__(self, path, dataset: str | None = None):
        from scipy.io import loadmat
        from scipy.io.matlab import MatReadError

        self.path = os.fspath(path)
        try:
            data = loadmat(self.path, variable_names=None if dataset is None else [dataset])
        except FileNotFoundError:
            raise InputError("file not found", path) from None
        except (MatReadError, ValueError, TypeError, OSError, IndexError, EOFError,
                NotImplementedError, zlib.error) as exc:
            raise InputError(f"not a readable MAT-file ({_short(exc)})", path) from None
        if dataset is not None and dataset not in data:
            raise InputError(f"no variable {dataset!r} in the file", path)
        found = [k for k, v in data.items() if not k.startswith("__")
                 and isinstance(v, np.ndarray) and v.ndim == 3 and v.dtype.kind in "uif"]
        name = dataset if dataset is not None else _only_variable(found, self.path)
        frames = np.asarray(data[name])
        if frames.ndim != 3:
            raise InputError(f"variable {name!r} is {frames.ndim}-D; expected H x W x T",
                             path)
        self._array = np.moveaxis(frames, 2, 0)                      # (T, H, W)
        self._set_dtype(self._array.shape, self._array.dtype)
        self.shape = tuple(int(n) for n in self._array.shape)

    def _read(self, start, stop):
        return np.ascontiguousarray(self._array[start:stop])


def _only_variable(names: list[str], path) -> str:
    """The one MATLAB variable of ``names`` (3-D numeric ones), else an InputError."""
    if not names:
        raise InputError("no 3-D numeric variable (H x W x T) in the MAT-file", path)
    if len(names) > 1:
        raise InputError(f"several 3-D variables ({', '.join(names)}); choose one with "
                         "--dataset", path)
    return names[0]


def _text(value) -> str | None:
    """An HDF5 string attribute as str (h5py gives bytes or str)."""
    return value.decode() if isinstance(value, bytes) else value


def is_matlab_hdf5(path) -> bool:
    """True when the file is a MATLAB MAT-file of version 7.3 (its header's text)."""
    with open(path, "rb") as f:
        return f.read(len(MATLAB_HDF5)) == MATLAB_HDF5


def _frame_rate(value, path) -> float | None:
    """The ``frame_rate`` attribute as a positive number, or None when absent."""
    if value is None:
        return None
    try:
        rate = float(np.asarray(value).reshape(-1)[0]) if np.size(value) == 1 else None
    except (TypeError, ValueError):
        rate = None
    if rate is None or not (np.isfinite(rate) and rate > 0):
        raise InputError(f"attribute frame_rate must be one positive number, got {value!r}",
                         path)
    return rate


def _read_truth(file: h5py.File, path) -> np.ndarray | None:
    obj = file.get("truth")
    if not isinstance(obj, h5py.Dataset) or obj.dtype.names is None:
        return None
    raw = obj[()]
    missing = {"frame", "x", "y"} - set(raw.dtype.names)
    if missing:
        raise InputError(f"/truth lacks the fields {sorted(missing)}", path)
    out = tables.from_columns(tables.TRUTH, **{k: raw[k] for k in raw.dtype.names
                                               if k in tables.TRUTH.names})
    if "target" not in raw.dtype.names:
        out["target"] = 0
    return out


def natural_key(name: str):
    """Sort key that orders ``frame2`` before ``frame10``."""
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


def _images_in(folder: Path) -> list[Path]:
    return sorted((p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES
                   and p.is_file() and not p.name.startswith(".")),
                  key=lambda p: natural_key(p.name))


def numbering_gaps(files) -> list[tuple[str, str]]:
    """The places where the frame numbers of image names skip: (name before, name after)
    pairs, in order. Names are numbered when all share one text around their last number
    (``frame_0019.png``); otherwise, or with fewer than two names, there is none."""
    parts = [re.fullmatch(r"(.*?)(\d+)(\D*)", Path(f).name) for f in files]
    if len(parts) < 2 or not all(parts) or len({(m[1], m[3]) for m in parts}) > 1:
        return []
    numbers = [int(m[2]) for m in parts]
    return [(Path(a).name, Path(b).name) for a, b, i, j
            in zip(files, files[1:], numbers, numbers[1:]) if j != i + 1]


def folder_images(folder: str | os.PathLike) -> list[Path]:
    """The frames of an image-folder sequence, in natural order (empty if it is none).

    The folder's own images, or else those of its ``frames/`` subfolder when the folder
    holds no other sequence file (a recording folder: ``frames/`` with ``truth.txt``
    beside it, the layout of ``shared/data/real``; a folder that also holds .h5, .npy or
    video files is a folder of sequences). Hidden files are skipped.
    """
    folder = Path(folder)
    files = _images_in(folder)
    if not files and (folder / "frames").is_dir() and not any(
            p.suffix.lower() in HDF5_SUFFIXES | VIDEO_SUFFIXES | MAT_SUFFIXES | {".npy"}
            for p in folder.iterdir()):
        files = _images_in(folder / "frames")
    return files


class ImageFolderSource(FrameSource):
    """Frames from a folder of images, in natural sort order of their names.

    8- and 16-bit greyscale images are read as stored; colour images are converted to
    grey. Every image must have the size and type of the first one. A recording folder
    whose images sit in a ``frames/`` subfolder (with ``truth.txt`` beside it, the layout
    of ``shared/data/real``) is read from that subfolder.
    """

    def __init__(self, path):
        self.path = os.fspath(path)
        folder = Path(path)
        self._files = folder_images(folder)
        if not self._files:
            raise InputError("the folder holds no images (PNG, TIFF, BMP, JPEG, PGM)", path)
        first = self._load(self._files[0])
        self._set_dtype((len(self._files),) + first.shape, first.dtype)
        gaps = numbering_gaps(self._files)
        if gaps:
            # the images are taken as consecutive frames: a missing one doubles a
            # target's step there, which the trackers' motion models do not expect
            log.warning("%s: the frame numbers skip at %s (%d place%s); the images are "
                        "taken as consecutive frames", self.path,
                        ", ".join(f"{a} -> {b}" for a, b in gaps[:3])
                        + (", ..." if len(gaps) > 3 else ""),
                        len(gaps), "" if len(gaps) == 1 else "s")
        self.shape = (len(self._files),) + first.shape

    def _load(self, file: Path) -> np.ndarray:
        image = cv2.imread(str(file), cv2.IMREAD_ANYDEPTH | cv2.IMREAD_ANYCOLOR)
        if image is None:
            raise InputError("cannot read this image", file)
        if image.ndim == 3:
            code = cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY
            image = cv2.cvtColor(image, code)
        return image

    def _read(self, start, stop):
        out = np.empty((stop - start,) + self.shape[1:], dtype=self.dtype)
        for i, file in enumerate(self._files[start:stop]):
            image = self._load(file)
            if image.shape != self.shape[1:] or image.dtype != self.stored_dtype:
                raise InputError(f"frames of mixed sizes or types: {file.name} is "
                                 f"{image.shape[1]}x{image.shape[0]} {image.dtype}, the first is "
                                 f"{self.shape[2]}x{self.shape[1]} {self.stored_dtype}",
                                 self.path)
            out[i] = image
        return out


#: the codecs (OpenCV's FOURCC tag of a decoded stream, lower case) that discard
#: information: a still scene's faint structure changes in steps where they refresh it,
#: which the combined-frame path can read as dim slow targets (docs/real.md, "The
#: sequences compressed")
LOSSY_CODECS = frozenset({"fmp4", "mp4v", "xvid", "divx", "dx50", "h264", "avc1", "x264",
                          "hevc", "hvc1", "hev1", "h265", "vp80", "vp90", "vp09", "av01",
                          "mjpg", "mpg1", "mpg2", "wmv1", "wmv2", "wmv3", "theo"})


class VideoSource(FrameSource):
    """Frames of a video file decoded by OpenCV, converted to 8-bit grey.

    Decoding is sequential; reading frames in order (as ``windows`` does) costs one pass.
    """

    def __init__(self, path):
        self.path = os.fspath(path)
        if not os.path.exists(self.path):
            raise InputError("file not found", path)
        cap = cv2.VideoCapture(self.path)
        if not cap.isOpened():
            raise InputError("not a video OpenCV can decode", path)
        count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        ok, first = cap.read()
        cap.release()
        if not ok:
            raise InputError("the video has 0 frames", path)
        if count <= 0:
            count = self._count_frames()
        first = _grey(first)
        self.shape = (count,) + first.shape
        self.dtype = self.stored_dtype = first.dtype
        probe = cv2.VideoCapture(self.path)
        rate = probe.get(cv2.CAP_PROP_FPS)
        tag = int(probe.get(cv2.CAP_PROP_FOURCC))
        probe.release()
        self.frame_rate = float(rate) if rate and rate > 0 else None
        self.codec = (tag.to_bytes(4, "little").decode("latin-1").strip().lower()
                      if tag > 0 else None)
        self._cap = None
        self._next = 0

    def _count_frames(self):
        cap, n = cv2.VideoCapture(self.path), 0
        while cap.grab():
            n += 1
        cap.release()
        return n

    def _read(self, start, stop):
        if self._cap is None or start != self._next:
            if self._cap is not None:
                self._cap.release()
            self._cap = cv2.VideoCapture(self.path)
            self._cap.set(cv2.CAP_PROP_POS_FRAMES, start)
        out = np.empty((stop - start,) + self.shape[1:], dtype=self.dtype)
        for i in range(stop - start):
            ok, frame = self._cap.read()
            if not ok:
                raise InputError(f"video ends at frame {start + i}, expected {len(self)}",
                                 self.path)
            out[i] = _grey(frame)
        self._next = stop
        return out

    def close(self):
        if self._cap is not None:
            self._cap.release()
            self._cap = None


def _grey(frame):
    return cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY) if frame.ndim == 3 else frame


class NpySource(FrameSource):
    """Frames of a ``.npy`` file of shape (T, H, W), memory-mapped."""

    def __init__(self, path):
        self.path = os.fspath(path)
        try:
            self._array = np.load(self.path, mmap_mode="r", allow_pickle=False)
        except FileNotFoundError:
            raise InputError("file not found", path) from None
        except (ValueError, OSError, EOFError) as exc:
            raise InputError(f"not a readable .npy file ({_short(exc) or 'empty'})", path) \
                from None
        self._set_dtype(self._array.shape, self._array.dtype)
        self.shape = tuple(int(n) for n in self._array.shape)

    def _read(self, start, stop):
        return np.array(self._array[start:stop])


#: TIFF compressions OpenCV's own libtiff decodes: none, LZW, Deflate (Adobe and legacy),
#: PackBits; tifffile needs ``imagecodecs`` for LZW (and JPEG, ZSTD, ...)
OPENCV_COMPRESSIONS = {1, 5, 8, 32946, 32773}


class TiffSource(FrameSource):
    """Frames of a multi-page TIFF or OME-TIFF stack, one page per frame, read lazily
    with ``tifffile`` (the ``tiff`` extra: ``pip install irdetect[tiff]``).

    The file's first image series must be a stack of greyscale pages of one size: axes of
    length 1 are dropped, what remains must be (T, H, W). 8/16-bit and float pages are
    read as stored. ImageJ's frame interval gives ``frame_rate``. A single page is not a
    sequence and is refused, as a single image of any other type is.

    Compressed pages (LZW, the default of OpenCV's ``imwritemulti``; Deflate, PackBits)
    are decoded by ``imagecodecs``, which the ``tiff`` extra installs; without it, pages
    that tifffile alone cannot decode are read by OpenCV (``cv2.imreadmulti``), which
    decodes uncompressed, LZW, Deflate and PackBits pages. A compression neither can
    decode is refused with the package to install; "corrupt" is kept for files whose
    pages cannot be decoded.
    """

    def __init__(self, path):
        self.path = os.fspath(path)
        try:
            import tifffile
        except ImportError:
            raise InputError("reading a TIFF stack needs tifffile: pip install irdetect[tiff]",
                             path) from None
        # a page that fails to decode raises its codec's error: imagecodecs' are
        # RuntimeErrors, tifffile's own Deflate fallback raises zlib.error
        self._errors = (tifffile.TiffFileError, OSError, ValueError, IndexError, KeyError,
                        RuntimeError, zlib.error)
        self._opencv = False        # read the pages with OpenCV (no codec in tifffile)
        # tifffile logs what it finds wrong in a damaged file; the InputError says it once
        logging.getLogger("tifffile").setLevel(logging.CRITICAL)
        try:
            self._file = tifffile.TiffFile(self.path)
        except FileNotFoundError:
            raise InputError("file not found", path) from None
        except self._errors as exc:
            raise InputError(f"not a readable TIFF file ({_short(exc)})", path) from None
        try:
            self._open()
        except InputError:
            self._file.close()
            raise
        except self._errors as exc:
            self._file.close()
            raise InputError(f"corrupt or truncated TIFF file ({_short(exc)})", path) from None

    def _open(self):
        series = self._file.series[0]
        shape = tuple(int(n) for n in series.shape)
        if "S" in series.axes:
            raise InputError("colour TIFF pages are not supported (expected greyscale)",
                             self.path)
        kept = [n for n in shape[:-2] if n > 1]
        if not kept:
            raise InputError("a single image is not a sequence; give a multi-page TIFF or "
                             "the folder of frames", self.path)
        if len(kept) > 1:
            raise InputError(f"the TIFF holds a {len(shape)}-D series (axes {series.axes}, "
                             f"shape {shape}); expected one stack of pages (T, H, W)",
                             self.path)
        self.shape = (kept[0],) + shape[-2:]
        if len(series.pages) != self.shape[0]:
            raise InputError(f"corrupt or truncated TIFF file ({len(series.pages)} pages "
                             f"readable of {self.shape[0]})", self.path)
        self._set_dtype(self.shape, series.dtype)
        self._series = series
        self._opencv = self._needs_opencv(tifffile_codecs())
        interval = (self._file.imagej_metadata or {}).get("finterval")
        self.frame_rate = 1.0 / float(interval) if interval else None
        self._read(0, 1)                       # a truncated file fails here, not mid-run
        self._read(self.shape[0] - 1, self.shape[0])

    def _needs_opencv(self, codecs) -> bool:
        """True when tifffile lacks the codec of the pages (imagecodecs is not installed)
        and OpenCV can read them in its stead; an InputError naming the package to
        install when neither can."""
        compressions, predictors = codecs
        key = self._series.keyframe
        if key.compression in compressions and key.predictor in predictors:
            return False
        what = (f"{_enum_name(key.compression)} compressed" if key.compression
                not in compressions else f"{_enum_name(key.predictor)} predicted")
        pages = [getattr(p, "index", None) for p in self._series.pages]
        if key.compression not in OPENCV_COMPRESSIONS or pages != list(range(len(pages))):
            raise InputError(f"{what} TIFF pages need the imagecodecs package: "
                             "pip install imagecodecs (or irdetect[tiff])", self.path)
        return True

    def _read_opencv(self, start, stop):
        """Pages [start, stop) decoded by OpenCV's libtiff."""
        with _opencv_quiet():           # libtiff's complaints: the InputError says it once
            ok, mats = cv2.imreadmulti(self.path, start, stop - start,
                                       flags=cv2.IMREAD_UNCHANGED)
        mats = list(mats) if ok else []
        if len(mats) != stop - start or any(
                m.shape != self.shape[1:] or m.dtype != self.stored_dtype for m in mats):
            raise InputError(f"corrupt or truncated TIFF file (pages {start}..{stop - 1} "
                             "cannot be decoded)", self.path)
        return np.stack(mats)

    def _read(self, start, stop):
        if stop <= start:
            return np.empty((0,) + self.shape[1:], self.dtype)
        if self._opencv:
            return self._read_opencv(start, stop)
        try:
            frames = self._file.asarray(key=range(start, stop), series=0)
        except ImportError:     # a codec tifffile has but whose module is missing (zstd)
            name = _enum_name(self._series.keyframe.compression)
            raise InputError(f"{name} compressed TIFF pages need the imagecodecs package: "
                             "pip install imagecodecs (or irdetect[tiff])", self.path) from None
        except self._errors as exc:
            raise InputError(f"corrupt or truncated TIFF file ({_short(exc)})",
                             self.path) from None
        return np.asarray(frames, self.dtype).reshape((stop - start,) + self.shape[1:])

    def close(self):
        self._file.close()


@contextmanager
def _opencv_quiet():
    """OpenCV's log silenced for the block (its libtiff logs each damaged strip)."""
    logging_ = cv2.utils.logging
    level = logging_.getLogLevel()
    logging_.setLogLevel(logging_.LOG_LEVEL_SILENT)
    try:
        yield
    finally:
        logging_.setLogLevel(level)


def tifffile_codecs():
    """(compressions, predictors): the containers of the TIFF compression and predictor
    codes tifffile can decode here (``code in compressions``)."""
    from tifffile import TIFF

    return TIFF.DECOMPRESSORS, TIFF.PREDICTORS


def _enum_name(code) -> str:
    return getattr(code, "name", str(code))


def open_sequence(path: str | os.PathLike, dataset: str | None = None) -> FrameSource:
    """Open an image sequence for lazy reading; the path decides the reader.

    Parameters
    ----------
    path : str or os.PathLike
        An HDF5 file, a folder of images, a multi-page TIFF, a video file, a ``.npy``
        file or a MATLAB MAT-file (a variable of H x W x T; any version).
    dataset : str, optional
        HDF5: the dataset path (default ``/frames``, else the only 3-D dataset); MAT-file:
        the variable (default: the only 3-D numeric one).

    Returns
    -------
    FrameSource
        Frames of shape (H, W); ``src[a:b]`` is an ndarray of shape (b - a, H, W).

    Raises
    ------
    InputError
        Missing file, unreadable or corrupt file, not 3-D, 0 frames, unsupported dtype.

    Examples
    --------
    >>> with open_sequence("seq.h5") as src:            # doctest: +SKIP
    ...     for start, frames in src.windows(12):
    ...         print(start, frames.shape)
    """
    p = Path(path)
    if p.is_dir():
        return ImageFolderSource(p)
    check_input_file(p)
    suffix = p.suffix.lower()
    if suffix == ".npy":
        return NpySource(p)
    if suffix in VIDEO_SUFFIXES:
        return VideoSource(p)
    if suffix in MAT_SUFFIXES or is_matlab_hdf5(p):
        return MatlabHDF5Source(p, dataset) if h5py.is_hdf5(p) else MatSource(p, dataset)
    if suffix in HDF5_SUFFIXES or h5py.is_hdf5(p):
        return HDF5Source(p, dataset)
    if suffix in TIFF_SUFFIXES:
        return TiffSource(p)
    if suffix in IMAGE_SUFFIXES:
        raise InputError("a single image is not a sequence; give the folder of frames", path)
    raise InputError("unknown input type (expected .h5, a folder of images, a multi-page "
                     "TIFF, a video, .npy or .mat)", path)


def _short(exc: Exception) -> str:
    return str(exc).splitlines()[0][:160]
