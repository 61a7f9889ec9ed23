"""Pairing rules shared by the nodes and the bag reader: images by stamp, camera_info beside them.

A frame is (left image, left info, right image, right info), input indices 0-3; camera_info inputs 1 and 3
carry the stamps of inputs 0 and 2. Messages here are strings naming what they are, so a test reads
which message went into which set.
"""

from __future__ import annotations

import itertools
import random

import pytest

from stereo_depth.errors import ParameterError
from stereo_depth.sync import Synchronizer

STEREO = {1: 0, 3: 2}
MS = 1_000_000


def stereo_sync(**kwargs: object) -> Synchronizer:
    return Synchronizer(4, calibrations=STEREO, **kwargs)  # type: ignore[arg-type]


def message(index: int, frame: int, calibration: str = "A") -> str:
    kind = ("left", "left_info", "right", "right_info")[index]
    return f"{kind}{frame}" + (f":{calibration}" if index in STEREO else "")


def feed(sync: Synchronizer, arrivals: list[tuple[int, int]]) -> list[tuple[int, tuple[str, ...]]]:
    """(input, frame) in arrival order; frame f is stamped f * 33 ms."""
    sets = []
    for index, frame in arrivals:
        sets += sync.add(index, frame * 33 * MS, message(index, frame))
    return sets + sync.flush()


def frames_in_order(order: tuple[int, ...], frames: int) -> list[tuple[int, int]]:
    return [(index, frame) for frame in range(1, frames + 1) for index in order]


@pytest.mark.parametrize("order", list(itertools.permutations(range(4))))
def test_every_publish_order_pairs_every_frame_with_its_own_camera_info(order: tuple[int, ...]) -> None:
    sync = stereo_sync()
    sets = feed(sync, frames_in_order(order, 20))
    assert [messages for _, messages in sets] == [tuple(message(i, frame) for i in range(4)) for frame in range(1, 21)]
    assert sync.counters.dropped == 0 and sum(sync.counters.substituted) == 0 and sync.pending() == 0


def test_lost_camera_info_never_costs_the_frame_the_last_one_serves_and_is_counted() -> None:
    arrivals = [a for a in frames_in_order((1, 3, 0, 2), 30) if a not in {(1, 5), (3, 6), (1, 7), (3, 7), (3, 30)}]
    sync = stereo_sync()
    sets = feed(sync, arrivals)
    assert [stamp for stamp, _ in sets] == [frame * 33 * MS for frame in range(1, 31)]
    by_frame = dict(zip(range(1, 31), (m for _, m in sets), strict=True))
    assert by_frame[5][1] == message(1, 4) and by_frame[6][3] == message(3, 5)
    assert by_frame[7][1:4:2] == (message(1, 6), message(3, 5))
    assert by_frame[30][3] == message(3, 29)  # the bag's end: flush() uses the last one too
    assert sync.counters.substituted == [0, 2, 0, 3]
    assert sync.counters.matched == 30 and sync.counters.dropped == 0


def test_camera_info_repaired_late_is_counted_as_late_and_nothing_else() -> None:
    arrivals = frames_in_order((1, 3, 0, 2), 12)
    arrivals.remove((1, 4))
    arrivals.insert(arrivals.index((0, 9)), (1, 4))  # a reliable writer's repair, 5 frames later
    sync = stereo_sync()
    sets = feed(sync, arrivals)
    assert len(sets) == 12
    assert sync.counters.late == [0, 1, 0, 0] and sync.counters.substituted == [0, 1, 0, 0]
    assert sync.counters.stale == 0 and sync.counters.dropped == 0


def test_camera_info_repaired_seconds_late_at_1_hz_pairs_or_is_late_and_never_restarts_pairing() -> None:
    """At 1 Hz a reliable writer repairs a lost camera_info only after a heartbeat, 4 s later here, and
    delivers the samples it held back behind it, in order: old stamps, but not a looping bag."""
    on_time = [(index, frame, frame) for frame in range(1, 13) for index in (1, 3, 0, 2)]  # (input, frame, arrival)
    repaired = [(i, f, 8.5 if i == 1 and 4 <= f <= 8 else t) for i, f, t in on_time]
    sync = stereo_sync()
    sets = []
    for index, frame, _ in sorted(repaired, key=lambda a: a[2]):  # stable: same-time arrivals keep their order
        sets += sync.add(index, frame * 1_000_000_000, message(index, frame))
    sets += sync.flush()
    assert [stamp // 1_000_000_000 for stamp, _ in sets] == list(range(1, 13))
    assert sync.counters.time_jumps == 0 and sync.counters.dropped == 0
    assert sync.counters.late == [0, 4, 0, 0] and sync.counters.substituted == [0, 4, 0, 0]


def test_images_that_go_back_restart_pairing() -> None:
    """A looping bag: the second loop pairs every frame again after one restart, whichever input shows
    the jump first, and a message of the first loop still in flight after the jump changes nothing."""
    for order in ((1, 3, 0, 2), (0, 2, 1, 3)):
        first_loop = frames_in_order(order, 40)
        straggler = first_loop.pop()  # the first loop's last message arrives just after the jump
        sync = stereo_sync()
        sets = feed(sync, [*first_loop, *frames_in_order(order, 40)[:1], straggler, *frames_in_order(order, 40)[1:]])
        assert [stamp // (33 * MS) for stamp, _ in sets] == [*range(1, 40), *range(1, 41)]
        assert sync.counters.time_jumps == 1 and sync.counters.stale == 1


def test_skewed_and_bursty_streams_pair_every_frame() -> None:
    """Right camera 3 frames behind the left; and all four topics arriving in bursts of 4 frames."""
    timeline = [(f + 0.1 * i, (i, f)) for f in range(1, 41) for i in (1, 0)]  # left: info, then image
    timeline += [(f + 3.5 + 0.1 * i, (i, f)) for f in range(1, 41) for i in (3, 2)]  # right, 3 frames late
    skewed = [arrival for _, arrival in sorted(timeline)]
    rng = random.Random(7)
    bursts = []  # 4 frames at a time, each topic in order (as DDS delivers it), the topics interleaved at random
    for first in range(1, 41, 4):
        waiting = [[(i, f) for f in range(first, first + 4)] for i in range(4)]
        while any(waiting):
            bursts.append(rng.choice([w for w in waiting if w]).pop(0))
    for arrivals in (skewed, bursts):
        sync = stereo_sync(queue_size=20)
        sets = feed(sync, arrivals)
        assert [stamp for stamp, _ in sets] == [frame * 33 * MS for frame in range(1, 41)]
        assert sync.counters.dropped == 0 and sync.pending() == 0
        # a set whose camera_info came after the next frame's images took the one before (same calibration)
        assert sum(sync.counters.substituted) == sum(sync.counters.late)


def test_calibration_change_without_its_camera_info_drops_that_frame_only() -> None:
    def same(a: str, b: str) -> bool:
        return a.split(":")[1] == b.split(":")[1]

    sync = stereo_sync(same_calibration=same)
    sets = []
    for frame in range(1, 9):
        calibration = "A" if frame < 5 else "B"  # the camera switched mode at frame 5, whose info is lost
        for index in (1, 3, 0, 2):
            if (index, frame) != (1, 5):
                sets += sync.add(index, frame * 33 * MS, message(index, frame, calibration))
    assert [stamp // (33 * MS) for stamp, _ in sets] == [1, 2, 3, 4, 6, 7, 8]
    assert sync.counters.calibration_unknown == 1
    assert all(m[1].endswith(":B") for _, m in sets[4:])


def test_a_lost_camera_info_is_not_stood_in_for_where_the_other_camera_changed() -> None:
    """A new rig (or mode) whose right camera_info is lost on its first frame: the old right one would
    pair a new left calibration with an old right one, so that frame is dropped, and counted."""

    def same(a: str, b: str) -> bool:
        return a.split(":")[1] == b.split(":")[1]

    sync = stereo_sync(same_calibration=same)
    sets = []
    for frame, calibration in ((1, "A"), (2, "A"), (3, "B")):
        for index in (1, 3, 0, 2):
            if (index, frame) != (3, 3):
                sets += sync.add(index, frame * 33 * MS, message(index, frame, calibration))
    sets += sync.flush()  # nothing after it tells what the right camera's calibration became
    assert [stamp // (33 * MS) for stamp, _ in sets] == [1, 2]
    assert sync.counters.calibration_unknown == 1 and sync.counters.substituted == [0, 0, 0, 0]


def test_images_alone_still_follow_the_exact_and_approximate_rules() -> None:
    exact = Synchronizer(2)
    assert exact.add(0, 10, "l") == [] and exact.add(1, 11, "r") == []
    assert exact.add(1, 10, "r10") == [(10, ("l", "r10"))]
    approximate = Synchronizer(2, approximate=True, tolerance_ns=5)
    assert approximate.add(0, 10, "l") == [] and approximate.add(1, 13, "r") == [(10, ("l", "r"))]


def test_calibration_map_must_name_other_inputs() -> None:
    with pytest.raises(ParameterError, match="camera_info inputs"):
        Synchronizer(4, calibrations={0: 1})
    with pytest.raises(ParameterError, match="camera_info inputs"):
        Synchronizer(4, calibrations={1: 3, 3: 2})
