"""Threads for a frame's work: thread counts set per frame while numba is still loading (a node's second
matching thread calls `use_threads` while the first is importing numba, the census core, and must wait for
it, not fail), and a helper that works beside its caller on another core."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import threading

import pytest

from stereo_depth.core.threads import OtherCore, available_cores, current_core

# One thread sets the counts for frame after frame while the main thread imports numba, as a node does.
SCRIPT = textwrap.dedent(
    """
    import sys, threading
    from stereo_depth.core.threads import thread_counts, use_threads

    assert "numba" not in sys.modules
    errors, done = [], threading.Event()

    def frames():
        while not done.is_set():
            try:
                use_threads(1)
                thread_counts()
            except Exception as exc:
                errors.append(repr(exc))
                return

    worker = threading.Thread(target=frames)
    worker.start()
    import numba
    done.set()
    worker.join()
    print(errors or thread_counts())
    """
)


def test_thread_counts_set_while_numba_loads_wait_for_it() -> None:
    run = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=120, check=False)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip().startswith("{'opencv'"), run.stdout  # no error; numba's count read once loaded


@pytest.mark.skipif(available_cores() < 2, reason="needs two cores")
def test_a_helper_runs_its_callers_job_on_another_core() -> None:
    """The lower half of a frame must not share its caller's core (it would then take as long as the whole
    image), wherever the caller runs and whatever core the scheduler would pick for the helper."""
    seen: list[tuple[int, int | None, set[int]]] = []

    def caller(core: int) -> None:
        os.sched_setaffinity(0, {core})  # this thread only
        helper = OtherCore("test_helper")
        for _ in range(3):
            seen.append((core, *helper.submit(lambda: (current_core(), os.sched_getaffinity(0))).result()))

    for core in sorted(os.sched_getaffinity(os.getpid()))[:2]:
        thread = threading.Thread(target=caller, args=(core,))
        thread.start()
        thread.join(timeout=60)
        assert not thread.is_alive(), f"the caller on core {core} still waits for its helper's job"
    assert len(seen) == 6
    for caller_core, helper_core, helper_cores in seen:
        assert helper_core != caller_core
        assert caller_core not in helper_cores
        assert helper_cores <= os.sched_getaffinity(os.getpid())  # the process's share still applies
