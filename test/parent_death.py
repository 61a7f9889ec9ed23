"""Processes a test run starts end with it: a pytest killed (a CI job cancelled, Ctrl-C twice, a crash)
takes its xdist workers and their node processes along, so none answers the next run on its domain id.

Linux's PR_SET_PDEATHSIG: the kernel sends SIGKILL to a process when the thread that started it ends.
Node processes are started from pytest's main thread, and xdist starts its workers from its own, each
living as long as the run.
"""

from __future__ import annotations

import ctypes
import os
import signal

_PR_SET_PDEATHSIG = 1  # linux/prctl.h
_prctl = ctypes.CDLL(None, use_errno=True).prctl  # looked up at import, so a child after fork only calls it


def die_with_parent(parent: int) -> None:
    """Called in the child (a subprocess's preexec_fn, or an xdist worker at start): SIGKILL when `parent`,
    the process that started this one, dies; at once if it already has."""
    _prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() != parent:  # it died before the line above
        os._exit(1)
