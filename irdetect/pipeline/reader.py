"""The window reader: raw frames of one window and the history before it, streamed
through one reused buffer, and the camera's offsets and gain of every frame read
(measured once).
"""

from __future__ import annotations

import numpy as np

from irdetect.camera import CameraMotion
from irdetect.gain import STEP, SensorGain, normalise
from irdetect.io.sources import FrameSource, check_values
from irdetect.repeats import is_conversion, repeated_frames


class Reader:
    """Read windows [a, b) with the ``history`` raw frames before a, in the stored dtype.

    Frames go into one reused buffer of ``history + length + block`` frames, read ahead
    in blocks the storage favours (an HDF5 chunk: a compressed chunk read in pieces is
    decompressed once per piece), so memory is bounded whatever the sequence length.
    The arrays returned are views of the buffer, valid until the next ``read``; where the
    camera's gain control stepped (``irdetect.gain``, ``gain_step`` > 0) they are float32
    frames taken back to frame 0's gain and level instead.
    """

    #: largest read-ahead in bytes (a 64-frame chunk of 640x512 uint16 frames is 42 MB)
    MAX_BLOCK_BYTES = 48 << 20

    def __init__(self, frames, history: int, length: int, ahead: int = 0,
                 camera: bool = True, gain_step: float = STEP):
        self.frames = frames
        self.history = history
        n, h, w = (int(v) for v in frames.shape)
        self.n = n
        # the camera's offsets of every frame read, measured once, in order (zeros when
        # the configuration takes the camera to be still)
        self.motion = CameraMotion((h, w)) if camera else None
        self.offsets = np.zeros((n, 2))
        # the gain and level (G_t, O_t) of every frame read against frame 0's
        if not 0.0 <= gain_step < 1.0:
            raise ValueError(f"suppress.gain_step must be in [0, 1), got {gain_step!r}")
        self.agc = SensorGain(gain_step) if gain_step > 0 else None
        self.gains = np.tile([1.0, 0.0], (n, 1))
        self.measured = 0           # frames [0, measured) have offsets and gains
        # frames equal to the frame before them, and the last frame measured
        self.repeats: list[int] = []
        self._last: np.ndarray | None = None
        # the raw values an integer sensor clips at (``normalise``)
        kind = np.dtype(frames.dtype)
        self.limits = ((np.iinfo(kind).min, np.iinfo(kind).max) if kind.kind in "iu"
                       else None)
        frame_bytes = h * w * kind.itemsize
        chunk = max(1, int(getattr(frames, "block_frames", 1)))
        self.block = max(length, min(chunk, max(1, self.MAX_BLOCK_BYTES // frame_bytes)))
        # the first window may also read ``ahead`` frames after it (it has no history)
        size = max(history + length + self.block, length + ahead)
        self.buf = np.empty((min(n, size), h, w), frames.dtype)
        self.lo = self.hi = 0     # the buffer holds raw frames [lo, hi)

    def read(self, a: int, b: int):
        lo = max(0, a - self.history)
        if not self.lo <= lo <= self.hi:
            self.lo = self.hi = lo
        if b > self.hi:
            keep = self.hi - lo
            if lo > self.lo:            # drop frames before lo: move the rest to the front
                self.buf[:keep] = self.buf[lo - self.lo:self.hi - self.lo]
            self.lo = lo
            stop = min(self.n, max(b, self.hi + self.block), lo + len(self.buf))
            self._fill(self.hi, stop, self.buf[keep:keep + stop - self.hi])
            self.hi = stop
        data = self.buf[lo - self.lo:b - self.lo]
        gains = self.gains[lo:b]
        if (gains != (1.0, 0.0)).any():
            data = normalise(data, gains, self.limits)
        return data[a - lo:], data[:a - lo]

    def _fill(self, start: int, stop: int, out: np.ndarray) -> None:
        if hasattr(self.frames, "read_into"):
            self.frames.read_into(start, stop, out)
        else:
            out[...] = self.frames[start:stop]
        # a file's frames must be finite (docs/format.md; arrays given to detect_sequence
        # may hold NaN, which finds nothing there): one pass, no warning, no mask
        if isinstance(self.frames, FrameSource):
            check_values(out, start, getattr(self.frames, "path", None))
        if stop > self.measured:
            # frames skipped (windows with gaps) keep the last offset and gain
            first = max(start, self.measured)
            if self.measured:
                self.offsets[self.measured:first] = self.offsets[self.measured - 1]
                self.gains[self.measured:first] = self.gains[self.measured - 1]
            if self.motion is not None:
                self.offsets[first:stop] = self.motion.update(out[first - start:])
            if self.agc is not None:
                self.gains[first:stop] = self.agc.update(out[first - start:],
                                                         self.offsets[first:stop])
            new = out[first - start:]
            prev = self._last if first == self.measured else None
            self.repeats.extend((first + repeated_frames(new, prev)).tolist())
            self._last = new[-1].copy()
            self.measured = stop

    def repeated(self, shown: int = 5) -> str | None:
        """One line on the frames read that repeat the frame before them exactly, when
        they are a frame-rate conversion's (``irdetect.repeats.is_conversion``); None
        otherwise, and when every one does (a still image, which ``flat_frames`` reports).
        The recordings hold a lone repeat now and then (4 of the 17 real folders one each),
        which is a frame like any other."""
        n = len(self.repeats)
        if not is_conversion(n, self.measured) or n >= self.measured - 1:
            return None
        listed = ", ".join(map(str, self.repeats[:shown]))
        more = f" and {n - shown} more" if n > shown else ""
        return (f"{n} frames ({listed}{more}) repeat the frame before them exactly (a "
                "frame-rate conversion, or a codec that copied them): no new observations, "
                "where a target seems to stop and then to jump; the sensor's own frames are "
                "better (docs/real.md, \"Repeated frames\")")

    def gain_steps(self) -> str | None:
        """One line on the gain steps taken so far (``SensorGain.summary``), or None."""
        return None if self.agc is None else self.agc.summary()
