"""How many threads OpenCV and numba may use for one frame's work.

Both default to every core of the machine, which is right for one frame at a time on an idle
machine and wrong everywhere else: two fleet workers on two cores would each run two threads, and a
node matching two frames at once would run four. OpenCV's count is per process; numba's applies to
the parallel kernels launched by the calling thread, so each worker thread sets it for itself.
"""

from __future__ import annotations

import os
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import ModuleType

import cv2

_applied = threading.local()  # (count, numba loaded) last set by this thread


def available_cores() -> int:
    """The cores this process may run on (its affinity mask: a container's or taskset's share)."""
    return len(os.sched_getaffinity(0))


def use_threads(requested: int, sharing: int = 1) -> int:
    """Give the work that follows on this thread `requested` threads, or with 0 this process's cores
    divided among `sharing` frames processed at once; returns the count. Cheap to call per frame: it
    acts only when the count changes or numba was loaded since (the census_sgm matcher loads it)."""
    count = requested if requested > 0 else max(1, available_cores() // max(sharing, 1))
    numba = _numba_if_loaded()
    key = (count, numba is not None)
    if getattr(_applied, "key", None) != key:
        cv2.setNumThreads(count)
        if numba is not None:
            numba.set_num_threads(min(count, numba.config.NUMBA_NUM_THREADS))
        _applied.key = key
    return count


def thread_counts() -> dict[str, int]:
    """The threads OpenCV and (once loaded) numba use for work started on this thread."""
    counts = {"opencv": cv2.getNumThreads()}
    numba = _numba_if_loaded()
    if numba is not None:
        counts["numba"] = numba.get_num_threads()
    return counts


def _numba_if_loaded() -> ModuleType | None:
    """numba once some code has imported it, else None (it is not loaded for its thread count alone).
    While another thread is still importing it, sys.modules already holds the half-built module; the
    import statement waits for that thread to finish, where sys.modules would hand it over unfinished."""
    if "numba" not in sys.modules:
        return None
    import numba  # waits for a thread that is still importing it (see above)

    return numba


@contextmanager
def opencv_threads(count: int) -> Iterator[None]:
    """OpenCV's thread count for the work inside, then the count before. Process-wide, as OpenCV's is:
    other threads' OpenCV calls meanwhile use it too (for `Halves`, whose two threads fill the cores)."""
    before = cv2.getNumThreads()
    cv2.setNumThreads(count)
    try:
        yield
    finally:
        cv2.setNumThreads(before)
