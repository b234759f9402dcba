"""Compiled kernels (numba) of the per-pixel and per-chain loops of the stages.

One module per stage they speed up: ``sampling`` (the verification's track sums, coarse
grid and hill climb), ``peaks`` (the per-frame path's local maxima). Every kernel is ``njit(cache=True, nogil=True)`` (``jit``): compiled on its first call after an
install and cached on disk (beside the module, or numba's user cache directory when the
package directory is read-only), and it releases the GIL, so the pipeline's worker
threads run kernels on both cores at once. ``warm_up`` compiles or loads them all before a
run, with one log line when they are compiled.
"""

from __future__ import annotations

import functools
import logging
import time

import numba

log = logging.getLogger(__name__)

#: the decorator of every kernel
jit = functools.partial(numba.njit, cache=True, nogil=True)

_warm: set = set()


def _cached(dispatcher) -> bool:
    """Whether numba's on-disk cache holds an index for ``dispatcher`` (False when it
    cannot tell)."""
    try:
        cache = dispatcher._cache
        return bool(cache._cache_file._load_index())
    except Exception:                                    # noqa: BLE001 - numba internals
        return False


def warm_up(*names: str) -> float:
    """Compile (first run after an install) or load the kernels of the modules ``names``
    (``"sampling"``, ``"peaks"``; all when none are given), once per process.

    Logs "compiling kernels, once" at INFO when a kernel is not in the cache. Returns the
    seconds taken (0 when already done in this process). A run loads only the kernels its
    stages use: the first costs about 0.5 s (numba's code generator starting), which the
    fast profile, using none, does not pay.
    """
    import importlib

    todo = [n for n in (names or ("sampling", "peaks")) if n not in _warm]
    if not todo:
        return 0.0
    t0 = time.perf_counter()
    modules = [importlib.import_module(f"irdetect.kernels.{n}") for n in todo]
    if not all(_cached(k) for m in modules for k in m.KERNELS):
        log.info("compiling kernels, once (later runs load them from numba's cache)")
    for m in modules:
        m.warm_up()
    _warm.update(todo)
    return time.perf_counter() - t0
