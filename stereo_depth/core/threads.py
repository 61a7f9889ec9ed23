"""How many threads OpenCV and numba may use for one frame's work, and a helper thread that works on
another core than its caller.

Both default to every core of the machine, which is right for one frame at a time on an idle
machine and wrong everywhere else: two fleet workers on two cores would each run two threads, and a
node matching two frames at once would run four. OpenCV's count is per process; numba's applies to
the parallel kernels launched by the calling thread, so each worker thread sets it for itself.
"""

from __future__ import annotations

import ctypes
import functools
import os
import sys
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager
from types import ModuleType
from typing import TypeVar

import cv2

T = TypeVar("T")

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


class OtherCore:
    """One thread that runs work beside the thread that submits it, on another core than that thread's.

    Linux wakes a sleeping thread on the core of the thread that woke it whenever it judges the other
    cores unavailable, which a VM's guest kernel does for a vCPU that its host has halted: after an idle
    moment (a node between two frames) the helper then shares its caller's core and both halves of a
    frame take as long as the whole image on one thread. Before each job this keeps the helper off the
    caller's current core (one affinity call; the process's own affinity, a container's or taskset's
    share, still applies). Where the cores cannot be told (one core allowed, no Linux affinity calls)
    the scheduler places it as usual."""

    def __init__(self, name: str) -> None:
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix=name)
        self._native_id = self._pool.submit(threading.get_native_id).result()

    def submit(self, job: Callable[[], T]) -> Future[T]:
        keep_off_current_core(self._native_id)
        return self._pool.submit(job)


_other_cores = threading.local()


def other_core(name: str) -> OtherCore:
    """The calling thread's own `OtherCore` helper (made on first use): each thread that matches frames
    (a node matching several at once) has its own, so each knows whose core to avoid."""
    helper: OtherCore | None = getattr(_other_cores, "helper", None)
    if helper is None:
        helper = _other_cores.helper = OtherCore(name)
    return helper


def keep_off_current_core(native_id: int) -> bool:
    """Let thread `native_id` run on any of the process's cores but the one the calling thread runs on now;
    False (nothing changed) where that is not possible."""
    current = current_core()
    if current is None:
        return False
    allowed = os.sched_getaffinity(os.getpid())  # the main thread's: the process's share
    others = allowed - {current}
    if not others:
        return False
    os.sched_setaffinity(native_id, others)
    return True


def current_core() -> int | None:
    """The core the calling thread runs on (glibc's sched_getcpu), None where that cannot be asked."""
    sched_getcpu = _sched_getcpu()
    if sched_getcpu is None:
        return None
    core = int(sched_getcpu())
    return core if core >= 0 else None


@functools.cache
def _sched_getcpu() -> Callable[[], int] | None:
    """glibc's sched_getcpu where affinities can be set (Linux), else None."""
    if not hasattr(os, "sched_setaffinity"):
        return None
    try:
        function: Callable[[], int] = ctypes.CDLL(None).sched_getcpu
    except (OSError, AttributeError):  # no C library to load, or one without sched_getcpu
        return None
    return function
