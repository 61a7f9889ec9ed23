"""Where tasks run: in this process, in a pool of local worker processes, or as Ray tasks.

Each backend yields results as tasks finish and, when the run is interrupted, cancels what is left
and waits for running tasks to unwind (their BagWriter deletes the half-written bag). Ray is imported
only when chosen: it is an optional dependency.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import signal
from collections.abc import Generator
from typing import Any, Protocol

from stereo_depth.core.params import StereoParams
from stereo_depth.errors import StereoDepthError
from stereo_depth.fleet.tasks import Task, TaskResult, matcher_cores, run_task, warm_up

CANCEL_GRACE_SECONDS = 10.0  # how long cancelled Ray tasks get to remove their partial output


Results = Generator[TaskResult, None, None]  # closing it cancels what has not finished


class Backend(Protocol):
    def run(self, tasks: list[Task]) -> Results: ...


class InProcess:
    """`--jobs 1`: one task after the other, here; Ctrl-C unwinds through process_bag itself."""

    def run(self, tasks: list[Task]) -> Results:
        for task in tasks:
            yield run_task(task)


_running = False  # in a pool worker: whether a task is under way


def _stop_worker(signum: int, frame: object) -> None:
    """SIGTERM from Pool.terminate: unwind a running task (its output is deleted), else just exit."""
    if _running:
        raise KeyboardInterrupt
    os._exit(0)


def _start_worker(params: StereoParams) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the driver alone handles Ctrl-C and stops the workers
    signal.signal(signal.SIGTERM, _stop_worker)
    warm_up(params)


def _pool_task(task: Task) -> TaskResult:
    global _running  # one flag per worker process, read by its signal handler
    _running = True
    try:
        return run_task(task)
    except KeyboardInterrupt:
        os._exit(130)  # the bag's temporary output is gone by now; leave nothing half-done behind
    finally:
        _running = False


class LocalPool:
    """`--jobs N`: N worker processes (spawned: no forked OpenCV or numba threads), each warmed once."""

    def __init__(self, jobs: int) -> None:
        self.jobs = jobs

    def run(self, tasks: list[Task]) -> Results:
        if not tasks:
            return
        context = multiprocessing.get_context("spawn")
        workers = min(self.jobs, len(tasks))
        pool = context.Pool(workers, initializer=_start_worker, initargs=(tasks[0].params,))
        try:
            yield from pool.imap_unordered(_pool_task, tasks, chunksize=1)
        except BaseException:
            pool.terminate()
            raise
        else:
            pool.close()
        finally:
            pool.join()


def import_ray() -> Any:
    try:
        import ray  # optional dependency, imported only for --ray
    except ImportError as exc:
        msg = "--ray needs Ray: pip install 'ray>=2.60' (or pip install .[ray] in this package)"
        raise StereoDepthError(msg) from exc
    return ray


class RayBackend:
    """`--ray [ADDRESS]`: every task a Ray task asking for the cores its matcher uses. No address
    starts a local Ray instance; `auto` or `ray://host:port` joins a running cluster, whose workers
    must reach the inputs and the output folder at the same paths (a shared file system)."""

    def __init__(self, address: str | None) -> None:
        self.address = address or None

    def run(self, tasks: list[Task]) -> Results:
        if not tasks:
            return
        ray = import_ray()
        started_here = not ray.is_initialized()
        if started_here:
            try:
                ray.init(
                    address=self.address or "local",
                    include_dashboard=False,
                    log_to_driver=False,
                    logging_level=logging.ERROR,
                )
            except (ConnectionError, RuntimeError, ValueError) as exc:
                msg = f"cannot start or join Ray at {self.address or 'a new local instance'}: {exc}"
                raise StereoDepthError(msg) from exc
        remote = ray.remote(num_cpus=matcher_cores(tasks[0].params), max_retries=0)(run_task)
        task_of = {remote.remote(task): task for task in tasks}
        pending = list(task_of)
        try:
            while pending:
                done, pending = ray.wait(pending, num_returns=1)
                try:
                    yield ray.get(done[0])
                except ray.exceptions.RayError as exc:  # the worker died (killed, out of memory): that task fails
                    task = task_of[done[0]]
                    yield TaskResult(task.bag, task.shard, error=f"Ray: {type(exc).__name__}: {exc}".splitlines()[0])
        except BaseException:
            self._cancel(ray, pending)
            raise
        finally:
            if started_here:
                ray.shutdown()

    @staticmethod
    def _cancel(ray: Any, pending: list[Any]) -> None:
        """Interrupt running tasks (KeyboardInterrupt in the worker: its output is deleted), give them
        a moment to unwind, then kill what is left; the caller sweeps any temporary folder they left."""
        for ref in pending:
            ray.cancel(ref)
        _, stuck = ray.wait(pending, num_returns=len(pending), timeout=CANCEL_GRACE_SECONDS)
        for ref in stuck:
            ray.cancel(ref, force=True)
