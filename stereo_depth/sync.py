"""Time synchronizer for 2-4 input streams (message_filters is not pip-installable).

Pure Python, no ROS import: the live nodes and the offline bag reader pair frames with the same rules.

- exact: a set is the messages of every input that carry the same stamp;
- approximate: one message per input whose stamps differ by at most `tolerance_ns`.

Queues are bounded (`queue_size` per input); a set never waits behind an older, incomplete one: when a
set is emitted, everything older is dropped and counted. A stamp that goes back by more than
`time_jump_ns` (a looping bag, a restarted driver) clears the queues instead of stalling them.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Any

from stereo_depth.errors import ParameterError


@dataclass
class SyncCounters:
    matched: int = 0
    dropped: int = 0  # messages that never became part of a set (unmatched, overflow, superseded)
    stale: int = 0  # messages older than the last emitted set
    time_jumps: int = 0
    dropped_by_input: list[int] = field(default_factory=list)


class Synchronizer:
    def __init__(
        self,
        n_inputs: int,
        queue_size: int = 5,
        approximate: bool = False,
        tolerance_ns: int = 0,
        time_jump_ns: int = 1_000_000_000,
    ) -> None:
        if not 2 <= n_inputs <= 4:
            msg = f"a synchronizer takes 2 to 4 inputs, not {n_inputs}"
            raise ParameterError(msg)
        if queue_size < 1:
            msg = f"queue_size {queue_size} must be at least 1"
            raise ParameterError(msg)
        if tolerance_ns < 0:
            msg = f"approximate sync tolerance {tolerance_ns} ns must not be negative"
            raise ParameterError(msg)
        self.n_inputs = n_inputs
        self.queue_size = queue_size
        self.approximate = approximate
        self.tolerance_ns = tolerance_ns if approximate else 0
        self.time_jump_ns = time_jump_ns
        self._queues: list[deque[tuple[int, Any]]] = [deque() for _ in range(n_inputs)]
        self._last_emitted: int | None = None
        self.counters = SyncCounters(dropped_by_input=[0] * n_inputs)

    def add(self, index: int, stamp_ns: int, message: Any) -> list[tuple[int, tuple[Any, ...]]]:
        """Queue one message; returns the sets it completed as (stamp of the first input, messages)."""
        if self._last_emitted is not None and stamp_ns <= self._last_emitted:
            if self._last_emitted - stamp_ns > self.time_jump_ns:
                self.reset()
                self.counters.time_jumps += 1
            else:
                self.counters.stale += 1
                return []
        queue = self._queues[index]
        if queue and stamp_ns < queue[-1][0]:
            # out of order within one input: keep the queue sorted
            items = sorted([*queue, (stamp_ns, message)], key=lambda item: item[0])
            queue.clear()
            queue.extend(items)
        else:
            queue.append((stamp_ns, message))
        while len(queue) > self.queue_size:
            queue.popleft()
            self._drop(index)
        return self._collect()

    def reset(self) -> None:
        for i, queue in enumerate(self._queues):
            for _ in queue:
                self._drop(i)
            queue.clear()
        self._last_emitted = None

    def pending(self) -> int:
        return sum(len(q) for q in self._queues)

    def _drop(self, index: int) -> None:
        self.counters.dropped += 1
        self.counters.dropped_by_input[index] += 1

    def _collect(self) -> list[tuple[int, tuple[Any, ...]]]:
        out: list[tuple[int, tuple[Any, ...]]] = []
        while True:
            found = self._find_exact() if not self.approximate else self._find_approximate()
            if found is None:
                return out
            out.append(self._emit(found))

    def _find_exact(self) -> list[int] | None:
        """Newest stamp that every input has, as the position in each queue."""
        common = set.intersection(*({s for s, _ in q} for q in self._queues))
        if not common:
            return None
        stamp = max(common)
        return [next(i for i, (s, _) in enumerate(q) if s == stamp) for q in self._queues]

    def _find_approximate(self) -> list[int] | None:
        """Heads-based search: drop heads that can no longer match, else pick the closest per input."""
        while all(self._queues):
            heads = [q[0][0] for q in self._queues]
            pivot = max(heads)
            oldest = min(range(self.n_inputs), key=lambda i: heads[i])
            if pivot - heads[oldest] > self.tolerance_ns:
                # Any set with this head also needs a message at or after `pivot`: it can never match.
                self._queues[oldest].popleft()
                self._drop(oldest)
                continue
            return [
                min(
                    (i for i, (s, _) in enumerate(q) if abs(s - pivot) <= self.tolerance_ns),
                    key=lambda i, q=q: abs(q[i][0] - pivot),  # type: ignore[misc]
                )
                for q in self._queues
            ]
        return None

    def _emit(self, positions: list[int]) -> tuple[int, tuple[Any, ...]]:
        """Pop the chosen message of each input; everything older in that input is dropped."""
        stamps, messages = [], []
        for index, (queue, position) in enumerate(zip(self._queues, positions, strict=True)):
            for _ in range(position):
                queue.popleft()
                self._drop(index)
            stamp, message = queue.popleft()
            stamps.append(stamp)
            messages.append(message)
        self.counters.matched += 1
        self._last_emitted = max(stamps)
        return stamps[0], tuple(messages)
