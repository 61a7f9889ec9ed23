"""Where tasks run: in this process, in a pool of local worker processes, or as Ray tasks.

Each backend yields results as tasks finish and, when the run is interrupted, cancels what is left
and waits for running tasks to unwind (their BagWriter deletes the half-written bag). Ray is imported
only when chosen: it is an optional dependency.
"""

from __future__ import annotations

import dataclasses
import logging
import multiprocessing
import os
import signal
import uuid
from collections.abc import Generator
from multiprocessing.connection import Connection, wait
from multiprocessing.context import SpawnContext
from pathlib import Path
from typing import Any, Protocol, cast

from stereo_depth.core.params import StereoParams
from stereo_depth.core.threads import available_cores
from stereo_depth.errors import StereoDepthError
from stereo_depth.fleet.tasks import Task, TaskResult, matcher_cores, run_task, warm_up

CANCEL_GRACE_SECONDS = 10.0  # how long cancelled tasks get to remove their partial output


Results = Generator[TaskResult, None, None]  # closing it cancels what has not finished


class Backend(Protocol):
    def run(self, tasks: list[Task]) -> Results: ...


class InProcess:
    """`--jobs 1`: one task after the other, here; Ctrl-C unwinds through process_bag itself."""

    def run(self, tasks: list[Task]) -> Results:
        for task in tasks:
            yield run_task(task)


_running = False  # in a worker process: whether a task is under way


def _stop_worker(signum: int, frame: object) -> None:
    """SIGTERM from the driver: unwind a running task (its output is deleted), else just exit."""
    if _running:
        raise KeyboardInterrupt
    os._exit(0)


def _serve(connection: Connection, params: StereoParams, threads: int) -> None:
    """A worker process: tasks in, results out over its own pipe, until the driver closes it.

    One pipe per worker and no lock shared between processes, so stopping a worker at any moment
    cannot leave the driver waiting (multiprocessing.Pool.terminate can hang on a lock an idle
    worker held). numba starts no more threads than the worker's share of the cores (it reads
    NUMBA_NUM_THREADS once, when loaded); each task sets OpenCV's and numba's counts to that share."""
    global _running  # one flag per worker process, read by its signal handler
    os.environ["NUMBA_NUM_THREADS"] = str(threads)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the driver alone handles Ctrl-C and stops the workers
    signal.signal(signal.SIGTERM, _stop_worker)
    warm_up(params)
    while True:
        try:
            task = connection.recv()
        except EOFError:
            return
        _running = True
        try:
            result = run_task(task)
        except KeyboardInterrupt:
            os._exit(130)  # the bag's temporary output is gone by now
        _running = False
        connection.send(result)


class _Worker:
    def __init__(self, context: SpawnContext, params: StereoParams, threads: int) -> None:
        self.connection, there = context.Pipe()
        self.process = context.Process(target=_serve, args=(there, params, threads), daemon=True)
        self.process.start()
        there.close()
        self.task: Task | None = None

    def submit(self, task: Task, threads: int) -> None:
        self.task = task
        self.connection.send(dataclasses.replace(task, threads=threads))

    def result(self) -> TaskResult:
        """The finished task's result; a dead worker (killed, out of memory) fails only its own task."""
        assert self.task is not None
        try:
            return cast("TaskResult", self.connection.recv())
        except EOFError:
            self.process.join()
            error = f"the worker process died (exit code {self.process.exitcode}) while processing this bag"
            return TaskResult(self.task.bag, self.task.shard, error=error)

    def stop(self, grace_seconds: float) -> None:
        if self.process.is_alive():
            self.process.terminate()
            self.process.join(grace_seconds)
        if self.process.is_alive():
            self.process.kill()
            self.process.join()
        self.connection.close()


class LocalPool:
    """`--jobs N`: N worker processes (spawned: no forked OpenCV or numba threads), each warmed once and
    each matching on its share of this process's cores."""

    def __init__(self, jobs: int) -> None:
        self.jobs = jobs

    def run(self, tasks: list[Task]) -> Results:
        if not tasks:
            return
        context = multiprocessing.get_context("spawn")
        params, waiting = tasks[0].params, list(reversed(tasks))
        count = min(self.jobs, len(tasks))
        share = max(1, available_cores() // count)
        workers = [_Worker(context, params, share) for _ in range(count)]
        try:
            for worker in workers:
                worker.submit(waiting.pop(), share)
            busy = {worker.connection: worker for worker in workers}
            while busy:
                for ready in wait(list(busy)):
                    worker = next(w for c, w in busy.items() if c is ready)
                    del busy[worker.connection]
                    result = worker.result()
                    if waiting:
                        if not worker.process.is_alive():  # it died: a fresh one takes the next task
                            workers.remove(worker)
                            worker.stop(0)
                            worker = _Worker(context, params, share)
                            workers.append(worker)
                        worker.submit(waiting.pop(), share)
                        busy[worker.connection] = worker
                    yield result
        finally:
            for worker in workers:  # Ctrl-C: running tasks unwind and delete their output first
                worker.stop(CANCEL_GRACE_SECONDS)


def import_ray() -> Any:
    try:
        import ray  # optional dependency, imported only for --ray
    except ImportError as exc:
        msg = "--ray needs Ray: pip install 'ray>=2.60' (or pip install .[ray] in this package)"
        raise StereoDepthError(msg) from exc
    return ray


class RayBackend:
    """`--ray [ADDRESS]`: every task a Ray task asking for the cores its matcher uses, and matching on
    as many OpenCV / numba threads. No address
    starts a local Ray instance; `auto` or `ray://host:port` joins a running cluster, whose workers
    must reach the inputs and the output folder at the same paths (a shared file system).

    An interrupted run stops its tasks through a file in the output folder (`Task.stop_file`), not
    with `ray.cancel`: Ray 2.x aborts the driver when a cancel crosses a task that is finishing
    ("Tried to complete task that was not pending", ray-project/ray#54798). Only a task that has not
    stopped after CANCEL_GRACE_SECONDS is cancelled by force."""

    def __init__(self, address: str | None, out_dir: Path) -> None:
        self.address = address or None
        self.stop_file = out_dir / f".stop-{uuid.uuid4().hex}"

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
        cores = matcher_cores(tasks[0].params)
        remote = ray.remote(num_cpus=cores, max_retries=0)(run_task)
        task_of = {
            remote.remote(dataclasses.replace(task, threads=cores, stop_file=self.stop_file)): task for task in tasks
        }
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

    def _cancel(self, ray: Any, pending: list[Any]) -> None:
        """Ask every task to stop (running ones delete their output, queued ones return at once), give
        them a moment, then kill what is left; the caller sweeps any temporary folder they left."""
        self.stop_file.touch()
        try:
            _, stuck = ray.wait(pending, num_returns=len(pending), timeout=CANCEL_GRACE_SECONDS)
            for ref in stuck:
                ray.cancel(ref, force=True)
        finally:
            self.stop_file.unlink()
