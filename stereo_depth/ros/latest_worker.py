"""The bounded queue between a node's inputs and its work, sized by the measured load.

Waiting places absorb bursts (DDS delivers large images in bunches, a busy machine stalls a thread for
a moment) while the node keeps up on average. Under sustained overload they would only add latency:
every frame would wait behind the ones before it. So the places a frame may wait in follow the
measured input rate and time per job: as many as the node can clear within `DRAIN_S` with its spare
rate, at least one (the newest set), at most `capacity` (max_waiting_frames). With a budget
(max_latency_ms), a frame that would be out later than that after its receipt is dropped before any
work is spent on it.
"""

from __future__ import annotations

import statistics
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

DRAIN_S = 1.0  # a backlog the node cannot clear within this time is latency, not a burst
RATE_WINDOW = 30  # arrivals over which the input rate is measured (spans a burst)
SERVICE_WINDOW = 10  # jobs over which the time per job is measured
MIN_JOBS = 3  # the time per job is known from this many: a node's first job also loads its compiled kernels
PROBE_S = 1.0  # while every frame misses the budget, one is still run this often to measure again


@dataclass
class Load:
    """Input rate and time per job, measured as jobs come and go (monotonic seconds)."""

    arrivals: deque[float] = field(default_factory=lambda: deque(maxlen=RATE_WINDOW))
    job_times: deque[float] = field(default_factory=lambda: deque(maxlen=SERVICE_WINDOW))

    def arrival_hz(self) -> float | None:
        if len(self.arrivals) < 5 or self.arrivals[-1] <= self.arrivals[0]:
            return None
        return (len(self.arrivals) - 1) / (self.arrivals[-1] - self.arrivals[0])

    def job_s(self) -> float | None:
        """The median: one job stalled by a busy machine is a hiccup the waiting places must ride out,
        not a reason to take them away. Unknown until MIN_JOBS have run: the first carries the start-up
        (numba's kernels loaded or compiled, caches cold) and alone would make a keeping-up node look
        overloaded."""
        return statistics.median(self.job_times) if len(self.job_times) >= MIN_JOBS else None

    def waiting_places(self, capacity: int, parallel: int) -> int:
        """1 when jobs come faster than `parallel` threads finish them; up to `capacity` when the spare
        rate clears that many within DRAIN_S; `capacity` until both rates are known."""
        hz, job_s = self.arrival_hz(), self.job_s()
        if hz is None or job_s is None or job_s <= 0:
            return capacity
        spare_hz = parallel / job_s - hz  # negative: slower than the input, the newest set only
        return max(1, min(capacity, 1 + int(DRAIN_S * spare_hz)))


class LatestWorker:
    """Runs jobs on `threads` threads, oldest first, at most `parallel` at once. The jobs waiting beyond
    `Load.waiting_places` are dropped oldest first (`on_dropped(False)`); with `budget_s` > 0, a job that
    would end later than that after its receipt is dropped as it would start (`on_dropped(True)`).
    Capacity 1: always the newest job. The limits are read as jobs come and go, so a parameter change
    applies to the next job."""

    def __init__(
        self,
        run: Callable[[Any], None],
        on_dropped: Callable[[bool], None],
        capacity: int = 1,
        threads: int = 1,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._run = run
        self._on_dropped = on_dropped
        self._clock = clock
        self.capacity = capacity
        self.parallel = 1
        self.budget_s = 0.0
        self.load = Load()
        self._running = 0
        self._last_run_s = clock()
        self._cond = threading.Condition()
        self._pending: deque[tuple[float, Any]] = deque()  # (receipt, job)
        self._stopped = False
        self._threads = [
            threading.Thread(target=self._loop, name=f"stereo_depth-worker-{i}", daemon=True) for i in range(threads)
        ]
        for thread in self._threads:
            thread.start()

    def submit(self, job: Any, received_s: float | None = None) -> None:
        """Queue `job`, received (input receipt, monotonic s) at `received_s`, by default now."""
        now = self._clock()
        with self._cond:
            self.load.arrivals.append(now)
            self._pending.append((now if received_s is None else received_s, job))
            places = self.load.waiting_places(max(self.capacity, 1), self.parallel)
            while len(self._pending) > places:
                self._pending.popleft()
                self._on_dropped(False)
            self._cond.notify_all()

    def stop(self) -> None:
        """Let the running jobs finish, discard the waiting ones, end the threads."""
        with self._cond:
            self._stopped = True
            self._pending.clear()
            self._cond.notify_all()
        for thread in self._threads:
            thread.join(timeout=30.0)

    def _next_job(self) -> Any:
        """The oldest waiting job that can still be out within the budget; None when none can."""
        now = self._clock()
        job_s = self.load.job_s()
        while self._pending:
            received_s, job = self._pending.popleft()
            late = self.budget_s > 0 and job_s is not None and now - received_s + job_s > self.budget_s
            probe = not self._pending and now - self._last_run_s > PROBE_S  # keeps job_s current
            if not late or probe:
                return job
            self._on_dropped(True)
        return None

    def _loop(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._stopped or (bool(self._pending) and self._running < self.parallel))
                if self._stopped:
                    return
                job = self._next_job()
                if job is None:
                    continue
                self._running += 1
            start = self._clock()
            try:
                self._run(job)
            finally:
                with self._cond:
                    self._last_run_s = self._clock()
                    self.load.job_times.append(self._last_run_s - start)
                    self._running -= 1
                    self._cond.notify_all()
