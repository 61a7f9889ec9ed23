"""An extra input stream (a colour camera, odometry) paired with the stereo sets by stamp only.

Pure Python, no ROS import: the live nodes and `process` pair with the same rules. Such streams are rarely
hardware-synchronised with the stereo pair, and the stereo outputs never wait for them, so this pairs
*after* the stereo set was processed, with its results as the payload:

- each extra message pairs with the stereo set nearest in stamp within `tolerance_ns` (ties: the
  earlier set); a stereo set may be chosen by several (an extra stream faster than the stereo pair) or
  by none, which `counters.unpaired_primary` counts once the set can no longer be chosen;
- a decision waits until it cannot change: until a stereo set at least as far past the extra message as
  its nearest one has been seen (so a colour image stamped just after its stereo set waits for the next
  set), or `flush`. The decisions therefore depend on the stamps alone, not on which stream's messages
  arrived first: a bag processed offline pairs as the same bag replayed into a node, as long as neither
  stream falls more than `keep` messages behind the other (the oldest are then given up, counted).

Each stream's stamps must grow; one that goes back (a looping bag, a restarted driver) starts that
stream afresh.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Generic, NamedTuple, TypeVar

PrimaryT = TypeVar("PrimaryT")
ExtraT = TypeVar("ExtraT")

KEEP = 16  # stereo sets, and extra messages, kept undecided at most (half a second at 30 Hz)


@dataclass
class PairingCounters:
    paired: int = 0
    unpaired_primary: int = 0  # stereo sets no extra message chose
    unpaired_extra: int = 0  # extra messages without a stereo set within the tolerance (or given up)


class Pair(NamedTuple, Generic[PrimaryT, ExtraT]):
    primary_ns: int
    primary: PrimaryT
    extra_ns: int
    extra: ExtraT


@dataclass
class _Primary(Generic[PrimaryT]):
    stamp_ns: int
    payload: PrimaryT
    chosen: bool = False


class NearestPairing(Generic[PrimaryT, ExtraT]):
    """Not thread-safe: the caller holds a lock when two threads add."""

    def __init__(self, tolerance_ns: int, keep: int = KEEP) -> None:
        self.tolerance_ns, self.keep = tolerance_ns, keep
        self.counters = PairingCounters()
        self._primaries: deque[_Primary[PrimaryT]] = deque()
        self._extras: deque[tuple[int, ExtraT]] = deque()  # undecided, oldest first
        self._newest_primary: int | None = None
        self._newest_extra: int | None = None

    def add_extra(self, stamp_ns: int, payload: ExtraT) -> None:
        """Keep an extra message until a stereo set decides it."""
        if self._newest_extra is not None and stamp_ns <= self._newest_extra:
            self.counters.unpaired_extra += len(self._extras)
            self._extras.clear()  # went back: this stream starts afresh
        self._extras.append((stamp_ns, payload))
        self._newest_extra = stamp_ns
        while len(self._extras) > self.keep:
            self._extras.popleft()
            self.counters.unpaired_extra += 1

    def add_primary(self, stamp_ns: int, payload: PrimaryT) -> list[Pair[PrimaryT, ExtraT]]:
        """A processed stereo set; returns the pairs its stamp decided, oldest extra message first."""
        if self._newest_primary is not None and stamp_ns <= self._newest_primary:
            self._retire(everything=True)  # went back: this stream starts afresh
        self._primaries.append(_Primary(stamp_ns, payload))
        self._newest_primary = stamp_ns
        pairs = self._decide(final=False)
        self._retire(everything=False)
        return pairs

    def flush(self) -> list[Pair[PrimaryT, ExtraT]]:
        """The end of the input: every extra message decided with the stereo sets seen, all forgotten."""
        pairs = self._decide(final=True)
        self.counters.unpaired_extra += len(self._extras)
        self._extras.clear()
        self._retire(everything=True)
        return pairs

    def _decide(self, final: bool) -> list[Pair[PrimaryT, ExtraT]]:
        pairs = []
        newest = self._newest_primary
        while self._extras and newest is not None:
            stamp, payload = self._extras[0]
            near = [p for p in self._primaries if abs(p.stamp_ns - stamp) <= self.tolerance_ns]
            best = min(near, key=lambda p: (abs(p.stamp_ns - stamp), p.stamp_ns), default=None)
            settled = newest >= stamp + self.tolerance_ns or (
                best is not None and newest >= stamp + abs(best.stamp_ns - stamp)
            )
            if not (settled or final):
                break  # a later stereo set may still be nearer; the extra messages after it wait too
            self._extras.popleft()
            if best is None:
                self.counters.unpaired_extra += 1
                continue
            best.chosen = True
            self.counters.paired += 1
            pairs.append(Pair(best.stamp_ns, best.payload, stamp, payload))
        return pairs

    def _retire(self, everything: bool) -> None:
        """Forget the stereo sets no extra message can choose any more (all of them: `everything`), and
        the oldest beyond `keep`; those never chosen are counted."""
        while self._primaries:
            oldest = self._primaries[0]
            reach = oldest.stamp_ns + self.tolerance_ns
            if self._extras:
                done = self._extras[0][0] > reach
            else:
                done = self._newest_extra is not None and self._newest_extra >= reach
            if not (everything or done or len(self._primaries) > self.keep):
                return
            self._primaries.popleft()
            self.counters.unpaired_primary += not oldest.chosen
