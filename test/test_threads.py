"""Thread counts set per frame while numba is still loading: a node's second matching thread calls
`use_threads` while the first is importing numba (the census core), and must wait for it, not fail."""

from __future__ import annotations

import subprocess
import sys
import textwrap

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
