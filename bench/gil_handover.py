"""What the GIL's hand-over interval costs a match that shares the process with a thread running Python.

In a node, the executor (taking and converting messages) and the cloud stage run Python beside the match.
The census core returns to Python between its kernels many times a frame, and each return waits for the
GIL until the thread holding it is asked to let go: every `sys.setswitchinterval` (5 ms by default, the
nodes' `GIL_SWITCH_S` in ros/node_main.py). OpenCV's SGBM is one call, so it waits once a frame.

Per matcher (`default`: OpenCV SGBM 3-way; `quality`: census_sgm, 6 paths) and interval (Python's 5 ms, the
nodes' 0.5 ms): median match ms alone and beside one thread running Python bytecode, on one long-lived
worker thread with the process's cores (as a node's first stage), interleaved frame by frame. 640x480
EuRoC pair, 128 disparities. With two cores, a busy second thread leaves the match one core: about 2x
its time alone is what sharing costs; more is the wait for the GIL.

    .venv/bin/python bench/gil_handover.py [--repeat 9]
"""

from __future__ import annotations

import argparse
import queue
import statistics
import sys
import threading
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from markdown_table import parse_bench_arguments, table_header, table_row, times
from pipeline_stages import load_pair

from stereo_depth.core.params import make_params
from stereo_depth.core.pipeline import StereoPipeline
from stereo_depth.core.threads import use_threads
from stereo_depth.ros.node_main import GIL_SWITCH_S

PYTHON_DEFAULT_S = 0.005
INTERVALS = {"5 ms (Python's)": PYTHON_DEFAULT_S, f"{GIL_SWITCH_S * 1000:g} ms (nodes')": GIL_SWITCH_S}


def python_thread(stop: threading.Event) -> None:
    """Bytecode and nothing else, as a thread converting messages or building them in Python."""
    total = 0
    while not stop.is_set():
        for i in range(1000):
            total += i


class Worker:
    """One long-lived thread that runs what it is given, with this process's cores for its numba and
    OpenCV work, as a node's first stage."""

    def __init__(self) -> None:
        self._jobs: queue.Queue[Callable[[], float] | None] = queue.Queue()
        self._results: queue.Queue[float] = queue.Queue()
        self._thread = threading.Thread(target=self._loop)
        self._thread.start()

    def run(self, work: Callable[[], float]) -> float:
        self._jobs.put(work)
        return self._results.get()

    def stop(self) -> None:
        self._jobs.put(None)
        self._thread.join()

    def _loop(self) -> None:
        use_threads(0)
        while (work := self._jobs.get()) is not None:
            self._results.put(work())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=9)
    args = parse_bench_arguments(parser)
    left, right, camera = load_pair(640, 480)
    pipelines = {name: StereoPipeline(make_params(name, {"disparity_range": 128})) for name in ("default", "quality")}

    def match_ms(pipeline: StereoPipeline) -> float:
        return float(pipeline.match(left, right, camera).timings_ms["match"])

    worker = Worker()
    for pipeline in pipelines.values():  # loads numba's kernels, warms the caches
        worker.run(partial(match_ms, pipeline))
    cases = [(name, interval, busy) for name in pipelines for interval in INTERVALS for busy in (False, True)]
    samples: dict[tuple[str, str, bool], list[float]] = {case: [] for case in cases}
    for _ in range(args.repeat):
        for name, interval, busy in cases:
            sys.setswitchinterval(INTERVALS[interval])
            stop = threading.Event()
            other = threading.Thread(target=python_thread, args=(stop,)) if busy else None
            if other is not None:
                other.start()
                time.sleep(0.05)
            samples[name, interval, busy].append(worker.run(partial(match_ms, pipelines[name])))
            stop.set()
            if other is not None:
                other.join()
    worker.stop()
    sys.setswitchinterval(PYTHON_DEFAULT_S)
    print(f"640x480, 128 disparities, {args.repeat} frames per case, interleaved; {time.strftime('%Y-%m-%d')}")
    columns = ("matcher", "GIL hand-over", "alone ms", "beside a Python thread ms", "beside / alone")
    print(table_header(columns) if args.markdown else "  ".join(columns))
    for name in pipelines:
        for interval in INTERVALS:
            alone, beside = (statistics.median(samples[name, interval, busy]) for busy in (False, True))
            cells = (name, interval, f"{alone:.1f}", f"{beside:.1f}", times(beside / alone))
            print(table_row(cells) if args.markdown else "  ".join(cells))


if __name__ == "__main__":
    main()
