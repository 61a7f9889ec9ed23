"""Time synchronizer for 2-4 input streams (message_filters is not pip-installable).

Pure Python, no ROS import: the live nodes and the offline bag reader pair frames with the same rules.

- exact: a set is the messages of every input that carry the same stamp;
- approximate: one message per input whose stamps differ by at most `tolerance_ns`.

Calibration inputs (camera_info) are paired differently from images, because over DDS they are the
messages most often lost: a reliable writer repairs a small sample only after its next periodic
heartbeat, by when its history has often moved on, and the transport drops the small samples first
when a burst of image fragments fills it (measured: bench/e2e_dds.py, docs/dds.md#any-publish-order-any-skew).
So `calibrations` maps each camera_info input to the input whose stamp it carries; the other inputs
(images, disparity) are paired as above, and each camera_info joins its image by stamp. When that
exact message is missing once the camera_info topic has moved past the stamp, or once the images of a
newer set are complete (a set waits one frame at most), the last camera_info serves instead (counted in
`substituted`), unless the calibration changed around that stamp (the set is dropped then, counted in
`calibration_unknown`). A camera_info that comes after its set went out is counted as `late`, never as an error.

Queues are bounded (`queue_size` per input); a set never waits behind an older, incomplete one: when a
set is emitted, everything older is dropped and counted. A stamp that goes back by more than
`time_jump_ns` against its own input's last stamp (a looping bag, a restarted driver) clears the queues
instead of stalling them; a message still in flight from before the jump is then `stale`. Judged per
input, because a camera_info that a reliable writer repairs seconds late (it delivers a topic's samples
in order, holding back the ones after it) is older than the last set but not than its own topic's last
message: it pairs, or is counted `late`, and pairing goes on.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from stereo_depth.errors import ParameterError
from stereo_depth.options import NodeOptions

Stamped = tuple[int, Any]
Choice = tuple[Stamped, bool] | None  # a camera_info and whether its stamp is the set's; None: unknown


@dataclass
class SyncCounters:
    matched: int = 0
    dropped: int = 0  # messages that never became part of a set (unmatched, overflow, superseded)
    stale: int = 0  # messages older than the last emitted set
    time_jumps: int = 0
    dropped_by_input: list[int] = field(default_factory=list)
    substituted: list[int] = field(default_factory=list)  # per input: sets that took the last camera_info
    late: list[int] = field(default_factory=list)  # per input: camera_infos that came after their set
    calibration_unknown: int = 0  # sets dropped: camera_info missing and the calibration changed there

    def copy(self) -> SyncCounters:
        return replace(
            self, dropped_by_input=list(self.dropped_by_input), substituted=list(self.substituted), late=list(self.late)
        )

    def since(self, before: SyncCounters) -> SyncCounters:
        """What happened between `before` (a copy) and now, counter by counter."""
        return SyncCounters(
            matched=self.matched - before.matched,
            dropped=self.dropped - before.dropped,
            stale=self.stale - before.stale,
            time_jumps=self.time_jumps - before.time_jumps,
            dropped_by_input=_minus(self.dropped_by_input, before.dropped_by_input),
            substituted=_minus(self.substituted, before.substituted),
            late=_minus(self.late, before.late),
            calibration_unknown=self.calibration_unknown - before.calibration_unknown,
        )


def _minus(now: list[int], before: list[int]) -> list[int]:
    return [a - b for a, b in zip(now, before, strict=True)]


def _always_same(_a: Any, _b: Any) -> bool:
    return True


class Synchronizer:
    def __init__(
        self,
        n_inputs: int,
        queue_size: int = NodeOptions().queue_size,  # its range is checked there
        approximate: bool = False,
        tolerance_ns: int = 0,
        time_jump_ns: int = 1_000_000_000,
        *,
        calibrations: Mapping[int, int] | None = None,
        same_calibration: Callable[[Any, Any], bool] = _always_same,
    ) -> None:
        if not 2 <= n_inputs <= 4:
            msg = f"a synchronizer takes 2 to 4 inputs, not {n_inputs}"
            raise ParameterError(msg)
        if tolerance_ns < 0:
            msg = f"approximate sync tolerance {tolerance_ns} ns must not be negative"
            raise ParameterError(msg)
        self.calibrations = dict(calibrations or {})
        if any(
            not (0 < i < n_inputs and 0 <= j < n_inputs) or j in self.calibrations for i, j in self.calibrations.items()
        ):
            msg = f"calibrations {self.calibrations} must map camera_info inputs (not input 0) to image inputs"
            raise ParameterError(msg)
        self.n_inputs = n_inputs
        self.queue_size = queue_size
        self.approximate = approximate
        self.tolerance_ns = tolerance_ns if approximate else 0
        self.time_jump_ns = time_jump_ns
        self.same_calibration = same_calibration
        self._primaries = [i for i in range(n_inputs) if i not in self.calibrations]
        self._queues: list[deque[Stamped]] = [deque() for _ in range(n_inputs)]
        self._last_used: dict[int, Stamped] = {}  # per camera_info input: the newest it knows before the queue
        self._last_emitted: int | None = None
        self._last_seen: dict[int, int] = {}  # per input: its newest stamp since the last time jump
        self._restarted_at = 1 << 62  # the stamp that jumped back last (none yet: nothing is before it)
        self.counters = SyncCounters(dropped_by_input=[0] * n_inputs, substituted=[0] * n_inputs, late=[0] * n_inputs)

    def add(self, index: int, stamp_ns: int, message: Any) -> list[tuple[int, tuple[Any, ...]]]:
        """Queue one message; returns the sets it completed as (stamp of the first input, messages)."""
        last_seen = self._last_seen.get(index)
        if last_seen is not None and last_seen - stamp_ns > self.time_jump_ns:
            self.reset()
            self.counters.time_jumps += 1
            self._restarted_at, last_seen = stamp_ns, None
        elif last_seen is None and stamp_ns - self._restarted_at > self.time_jump_ns:
            self.counters.stale += 1  # sent before the jump, arriving after it
            return []
        self._last_seen[index] = max(stamp_ns, last_seen or stamp_ns)
        if self._last_emitted is not None and stamp_ns <= self._last_emitted:
            if index in self.calibrations:
                self._late_calibration(index, stamp_ns, message)
                return []
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
            self._forget(index, queue.popleft())
        return self._collect(final=False)

    def flush(self) -> list[tuple[int, tuple[Any, ...]]]:
        """End of input (a bag's last message): sets that only wait for camera_info go out now."""
        return self._collect(final=True)

    def reset(self) -> None:
        for i, queue in enumerate(self._queues):
            for _ in queue:
                self._drop(i)
            queue.clear()
        self._last_used.clear()
        self._last_seen.clear()
        self._last_emitted = None

    def pending(self) -> int:
        return sum(len(q) for q in self._queues)

    def _drop(self, index: int) -> None:
        self.counters.dropped += 1
        self.counters.dropped_by_input[index] += 1

    def _forget(self, index: int, item: Stamped) -> None:
        """A message leaves its queue unused; a camera_info stays known as the newest calibration."""
        self._drop(index)
        if index in self.calibrations:
            self._remember(index, item)

    def _remember(self, index: int, item: Stamped) -> None:
        known = self._last_used.get(index)
        if known is None or item[0] > known[0]:
            self._last_used[index] = item

    def _late_calibration(self, index: int, stamp_ns: int, message: Any) -> None:
        self.counters.late[index] += 1
        self._remember(index, (stamp_ns, message))

    def _collect(self, final: bool) -> list[tuple[int, tuple[Any, ...]]]:
        out: list[tuple[int, tuple[Any, ...]]] = []
        while True:
            found = self._find_exact() if not self.approximate else self._find_approximate()
            if found is None:
                return out
            choice = self._choose_calibrations(found, force=final or self._must_go(found))
            if choice is None:
                return out  # waiting for a camera_info that may still come
            emitted = self._emit(found, choice)
            if emitted is not None:
                out.append(emitted)

    def _must_go(self, positions: dict[int, int]) -> bool:
        """A set waits for its camera_info only until the images of a newer set are complete (or an image
        queue is full): one frame period at most, so a stalled camera_info topic costs no frames."""
        if any(len(self._queues[i]) >= self.queue_size for i in self._primaries):
            return True
        if self.approximate:
            return all(len(self._queues[i]) > p + 1 for i, p in positions.items())
        stamp = self._queues[self._primaries[0]][positions[self._primaries[0]]][0]
        newer = ({s for s, _ in self._queues[i] if s > stamp} for i in self._primaries)
        return bool(set.intersection(*newer))

    def _find_exact(self) -> dict[int, int] | None:
        """Oldest stamp that every image input has, as the position in each queue."""
        common = sorted(set.intersection(*({s for s, _ in self._queues[i]} for i in self._primaries)))
        if not common:
            return None
        stamp = common[0]
        return {i: next(p for p, (s, _) in enumerate(self._queues[i]) if s == stamp) for i in self._primaries}

    def _find_approximate(self) -> dict[int, int] | None:
        """Heads-based search: drop heads that can no longer match, else pick the closest per input."""
        queues = {i: self._queues[i] for i in self._primaries}
        while all(queues.values()):
            heads = {i: q[0][0] for i, q in queues.items()}
            pivot = max(heads.values())
            oldest = min(heads, key=lambda i: heads[i])
            if pivot - heads[oldest] > self.tolerance_ns:
                # Any set with this head also needs a message at or after `pivot`: it can never match.
                self._drop(oldest)
                queues[oldest].popleft()
                continue
            return {
                i: min(
                    (p for p, (s, _) in enumerate(q) if abs(s - pivot) <= self.tolerance_ns),
                    key=lambda p, q=q: abs(q[p][0] - pivot),  # type: ignore[misc]
                )
                for i, q in queues.items()
            }
        return None

    def _choose_calibrations(self, positions: dict[int, int], force: bool) -> dict[int, Choice] | None:
        """Per camera_info input: the message for the set's stamp (exact: True), the last one when that
        will not come (False), or None when the calibration changed there and the set cannot be used;
        None overall: wait for it."""
        choice: dict[int, Choice] = {}
        for index, image in self.calibrations.items():
            stamp = self._queues[image][positions[image]][0]
            queue = self._queues[index]
            near = [item for item in queue if abs(item[0] - stamp) <= self.tolerance_ns]
            if near:
                choice[index] = (min(near, key=lambda item: abs(item[0] - stamp)), True)
                continue
            if not force and not any(s > stamp for s, _ in queue):
                return None
            substitute = self._substitute(index, stamp)
            choice[index] = None if substitute is None else (substitute, False)
        if any(c is not None and not c[1] for c in choice.values()) and self._rig_changed(choice):
            return dict.fromkeys(choice)  # another camera's calibration changed here: the last one is no proof
        return choice

    def _rig_changed(self, choice: dict[int, Choice]) -> bool:
        """Whether a camera_info of the set differs from the last one of its input."""
        return any(
            c is not None
            and c[1]
            and index in self._last_used
            and not self.same_calibration(self._last_used[index][1], c[0][1])
            for index, c in choice.items()
        )

    def _substitute(self, index: int, stamp: int) -> Stamped | None:
        """The newest camera_info before `stamp`, if the calibration did not change across `stamp`."""
        known = [*([self._last_used[index]] if index in self._last_used else []), *self._queues[index]]
        before = [item for item in known if item[0] < stamp]
        after = [item for item in known if item[0] > stamp]
        last = max(before, key=lambda item: item[0], default=None)
        following = min(after, key=lambda item: item[0], default=None)
        if last is not None and following is not None and not self.same_calibration(last[1], following[1]):
            return None
        return last if last is not None else following

    def _emit(self, positions: dict[int, int], calibrations: dict[int, Choice]) -> tuple[int, tuple[Any, ...]] | None:
        """Pop the chosen message of each input; everything older in that input is dropped. None when a
        camera_info could not be chosen: the images are dropped then."""
        stamps = [self._queues[i][p][0] for i, p in positions.items()]  # input 0 first
        messages: list[Any] = [None] * self.n_inputs
        for index, position in positions.items():
            queue = self._queues[index]
            for _ in range(position):
                self._drop(index)
                queue.popleft()
            messages[index] = queue.popleft()[1]
        self._last_emitted = max(stamps)
        unknown = False
        for index, choice in calibrations.items():
            chosen, exact = choice if choice is not None else (None, False)
            queue = self._queues[index]
            until = max(self._last_emitted, chosen[0] if exact and chosen is not None else 0)
            while queue and queue[0][0] <= until:
                item = queue.popleft()
                if item is not chosen:
                    self._forget(index, item)
            if chosen is None:
                unknown = True
                continue
            if not exact:
                self.counters.substituted[index] += 1
            self._remember(index, chosen)
            messages[index] = chosen[1]
        if unknown:
            self.counters.calibration_unknown += 1
            for index in positions:
                self._drop(index)
            return None
        self.counters.matched += 1
        return stamps[0], tuple(messages)


# A stereo camera's synchronizer inputs, in this order; each camera_info pairs by its image's stamp.
STEREO_INPUTS = ("left_image", "left_info", "right_image", "right_info")
STEREO_CALIBRATIONS = {1: 0, 3: 2}


@dataclass(frozen=True)
class StereoSet:
    """One matched set of a stereo camera's four inputs, by name: what the synchronizer pairs for the
    stereo nodes and for the bag reader alike, and what frames.decode_frame reads. Messages of either
    flavour (rclpy or rosbags); an image may be a CompressedImage; a missing input is None."""

    stamp_ns: int  # the set's stamp, as the synchronizer gave it
    left_image: Any
    left_info: Any
    right_image: Any
    right_info: Any
    lead_in: bool = False  # read before a shard's window only to fill the temporal filter (not written)

    @classmethod
    def paired(cls, stamp_ns: int, messages: Sequence[Any]) -> StereoSet:
        """A set of a synchronizer whose inputs are STEREO_INPUTS."""
        return cls(stamp_ns, **dict(zip(STEREO_INPUTS, messages, strict=True)))
