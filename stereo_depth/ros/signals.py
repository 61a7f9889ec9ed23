"""Ctrl-C and SIGTERM end a node with exit code 0 and no traceback, whenever they arrive.

The console scripts (`entry_points.py`) and `python -m stereo_depth.nodes.<node>` (the package's
`__init__`) install the handlers before a node's imports, which take a second or more; `run_node`
installs them for any other way in, and they stay in charge after `rclpy.init` (told to install none).
A signal only sets `SIGNALLED`: an exception raised at an arbitrary
bytecode comes out of an import as an ImportError, is printed and swallowed in a weakref callback or a
`__del__` (the node then runs on), or lands inside rclpy's C++ calls or its executor half-way through
building a Task. `run_node` looks at the flag before it starts rclpy, the spin loop within
SIGNAL_POLL_S; a node's start-up (well under a second) runs to its end first. Only a long start-up step
that is safe to cut (`interruptible`: numba's kernels, up to a minute on a fresh install) ends at once,
by SystemExit, which unwinds through the node's cleanup.

`kill -USR1 <pid>` prints the Python stack of every thread on stderr, from C, also while the main
thread is blocked in a C call and no Python handler can run.
"""

from __future__ import annotations

import faulthandler
import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType


class Flag:
    """A flag the signal handler may set and read. Not a threading.Event: its set() takes a lock, and
    Python runs a handler between any two bytecodes of the main thread, so a second signal's handler
    could run inside the first one's set(), with the lock held, and wait for it forever (seen in CI:
    a second SIGTERM right after the first). A bool is read and written whole under the GIL."""

    def __init__(self) -> None:
        self._value = False

    def set(self) -> None:
        self._value = True

    def clear(self) -> None:
        self._value = False

    def is_set(self) -> bool:
        return self._value


SIGNALLED = Flag()  # SIGINT / SIGTERM arrived: the process is on its way out
SPINNING = Flag()  # the node spins: a signal never raises, the spin loop ends
_CUTTABLE = Flag()  # inside `interruptible` during start-up: a signal raises SystemExit


def install() -> None:
    """The handlers, for this process (again: no change)."""
    faulthandler.register(signal.SIGUSR1, all_threads=True)
    if SIGNALLED.is_set():
        return  # a signal came already, and further ones stay ignored
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _on_signal)


@contextmanager
def interruptible() -> Iterator[None]:
    """A long start-up step that a signal may end at once (SystemExit) rather than after it is done.
    Not while the node spins (a lifecycle transition's callback): the exception would land in rclpy's
    executor; the spin loop ends after the callback instead."""
    if SPINNING.is_set() or threading.current_thread() is not threading.main_thread():
        yield
        return
    _CUTTABLE.set()
    try:
        if SIGNALLED.is_set():  # arrived before the step began
            raise SystemExit(0)
        yield
    finally:
        _CUTTABLE.clear()


def _on_signal(signum: int, frame: FrameType | None) -> None:
    del signum, frame
    SIGNALLED.set()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_IGN)  # a second signal must not interrupt the cleanup
    if _CUTTABLE.is_set():
        raise SystemExit(0)
