"""The queue in front of a node's work: bursts wait while the node keeps up on average, only the newest
set waits under sustained overload, and with a budget a set that could not be out in time is dropped
before any work is spent on it. Jobs sleep instead of computing, so a busy machine changes no outcome."""

from __future__ import annotations

import threading
import time

from ros_helpers import wait_until

from stereo_depth.ros.latest_worker import LatestWorker, Load


def load(arrival_hz: float, job_s: float) -> Load:
    measured = Load()
    measured.arrivals.extend(i / arrival_hz for i in range(30))
    measured.job_times.extend([job_s] * 10)
    return measured


def test_waiting_places_shrink_to_the_newest_set_as_the_node_falls_behind() -> None:
    assert Load().waiting_places(3, 1) == 3  # nothing measured yet: max_waiting_frames
    assert load(30.0, 0.010).waiting_places(3, 1) == 3  # keeps up with room to spare
    assert load(30.0, 0.032).waiting_places(3, 1) == 2  # 1.25 frames/s to spare: one burst frame cleared per 0.8 s
    assert load(30.0, 0.034).waiting_places(3, 1) == 1  # slower than the input: the newest only
    assert load(30.0, 0.050).waiting_places(3, 2) == 3  # two frames at once: 40 frames/s
    assert load(30.0, 0.010).waiting_places(1, 1) == 1  # never more than max_waiting_frames
    stalled = load(30.0, 0.010)
    stalled.job_times.extend([0.5, 0.5])  # a busy machine stalled two jobs: a hiccup, not overload
    assert stalled.waiting_places(3, 1) == 3
    starting = load(30.0, 0.010)
    starting.job_times.clear()
    starting.job_times.extend([5.0, 0.010])  # the first job loaded the kernels: not yet a measurement
    assert starting.waiting_places(3, 1) == 3


class Recorder:
    """Runs a job by sleeping `job_s`; remembers which jobs ran and which were dropped, and how."""

    def __init__(self, job_s: float, capacity: int) -> None:
        self.job_s = job_s
        self.ran: list[int] = []
        self.dropped: list[bool] = []
        self.submitted = 0
        self.lag: list[int] = []  # per job run: sets submitted after it by the time it started
        self.lock = threading.Lock()
        self.worker = LatestWorker(self.run, self.drop, capacity=capacity)

    def run(self, job: int) -> None:
        with self.lock:
            self.ran.append(job)
            self.lag.append(self.submitted - job)
        time.sleep(self.job_s)

    def drop(self, late: bool) -> None:
        with self.lock:
            self.dropped.append(late)

    def submit(self, received_s: float | None = None) -> None:
        with self.lock:
            self.submitted += 1
            job = self.submitted
        self.worker.submit(job, received_s)


def test_under_sustained_overload_each_set_processed_is_the_newest_one() -> None:
    recorder = Recorder(job_s=0.05, capacity=3)  # 20 sets/s served, 100 sent
    try:
        for _ in range(60):
            recorder.submit()
            time.sleep(0.01)
        wait_until(lambda: len(recorder.ran) + len(recorder.dropped) == recorder.submitted, "every set accounted for")
    finally:
        recorder.worker.stop()
    settled = recorder.lag[5:]  # once the rates are measured; one newer set may arrive as it starts
    assert settled and max(settled) <= 1, recorder.lag
    assert not any(recorder.dropped)  # replaced by newer sets, not late: there is no budget


def test_a_burst_waits_while_the_node_keeps_up_on_average() -> None:
    recorder = Recorder(job_s=0.005, capacity=3)
    try:
        for _ in range(20):  # 10 sets/s against 200 served
            recorder.submit()
            time.sleep(0.1)
        for _ in range(3):  # three at once, as DDS delivers large images after a repair
            recorder.submit()
        wait_until(lambda: len(recorder.ran) + len(recorder.dropped) == recorder.submitted, "every set accounted for")
    finally:
        recorder.worker.stop()
    assert recorder.ran == list(range(1, 24)) and not recorder.dropped


def test_with_a_budget_a_set_that_cannot_be_out_in_time_is_dropped_unprocessed() -> None:
    recorder = Recorder(job_s=0.05, capacity=3)
    recorder.worker.budget_s = 0.2
    try:
        for _ in range(3):  # measure the time per set: 50 ms
            recorder.submit()
            wait_until(lambda: recorder.ran == list(range(1, recorder.submitted + 1)), "the set before")
        recorder.submit(received_s=time.monotonic() - 0.18)  # 180 ms old + 50 ms of work: over the budget
        recorder.submit(received_s=time.monotonic() - 0.05)  # 50 + 50 ms: in time
        wait_until(lambda: len(recorder.ran) + len(recorder.dropped) == 5, "every set accounted for")
    finally:
        recorder.worker.stop()
    assert recorder.ran == [1, 2, 3, 5] and recorder.dropped == [True]
