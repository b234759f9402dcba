"""Seconds per stage (``timings`` dicts shared by threads) and a finished result with the
interface of a Future."""

from __future__ import annotations

import threading
import time

_LOCK = threading.Lock()


def lap(timings: dict | None, name: str, t0: float) -> float:
    """Add the seconds since ``t0`` to ``timings[name]``; return the current time."""
    t = time.perf_counter()
    if timings is not None:
        with _LOCK:
            timings[name] = timings.get(name, 0.0) + (t - t0)
    return t


class Ready:
    """A result computed on the calling thread, with the interface of a Future."""

    def __init__(self, value):
        self.value = value

    def result(self):
        return self.value
