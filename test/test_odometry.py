"""Odometry for the temporal filter (core/odometry.py): the pose at a frame's stamp, and when not to trust it."""

from __future__ import annotations

import math
import threading
import time

import numpy as np
import pytest

from stereo_depth.core.odometry import OdometrySample, OdometryTrack

MS = 1_000_000
WAIT_S = 0.1


def yaw(angle: float) -> tuple[float, float, float, float]:
    return (0.0, 0.0, math.sin(angle / 2.0), math.cos(angle / 2.0))


def driving(track: OdometryTrack, stamps_ms: list[int], speed: float = 1.0, turn: float = 0.5) -> None:
    """A robot driving forward at `speed` m/s while it turns at `turn` rad/s, its twist given."""
    for ms in stamps_ms:
        t = ms / 1000.0
        angle = turn * t
        # the arc's exact position for a constant speed and turn rate
        position = (speed / turn * math.sin(angle), speed / turn * (1.0 - math.cos(angle)), 0.0)
        track.add(OdometrySample(ms * MS, position, yaw(angle), (speed, 0.0, 0.0), (0.0, 0.0, turn)))


def test_the_pose_is_interpolated_between_the_messages_around_the_stamp() -> None:
    track = OdometryTrack()
    track.add(OdometrySample(0, (0.0, 0.0, 0.0), yaw(0.0)))
    track.add(OdometrySample(20 * MS, (0.2, 0.0, 0.0), yaw(0.2), (10.0, 0.0, 0.0), (0.0, 0.0, 10.0)))
    found = track.lookup(5 * MS, None, WAIT_S)
    assert found.pose is not None and not found.forget
    np.testing.assert_allclose(found.pose[:3, 3], [0.05, 0.0, 0.0], atol=1e-12)
    assert math.atan2(found.pose[1, 0], found.pose[0, 0]) == pytest.approx(0.05)  # slerp: a quarter of the turn
    exact = track.lookup(20 * MS, None, WAIT_S).pose
    assert exact is not None
    np.testing.assert_allclose(exact[:3, 3], [0.2, 0.0, 0.0])


def test_a_frame_before_its_odometry_has_no_pose_yet_and_keeps_the_history() -> None:
    track = OdometryTrack()
    driving(track, [0, 20, 40])
    late = track.lookup(45 * MS, 40 * MS, WAIT_S)  # the message after 45 ms has not come
    assert late.pose is None and not late.forget
    early = track.lookup(-5 * MS, None, WAIT_S)  # nothing before the stamp
    assert early.pose is None and not early.forget


@pytest.mark.parametrize(
    ("stamps_ms", "frame_ms"),
    [([0, 20, 400, 420], 200), ([0, 20, 40], 300)],
    ids=["a gap in the messages", "no message since"],
)
def test_odometry_that_stops_makes_the_filter_forget(stamps_ms: list[int], frame_ms: int) -> None:
    track = OdometryTrack()
    driving(track, stamps_ms)
    found = track.lookup(frame_ms * MS, (frame_ms - 33) * MS, WAIT_S)
    assert found.pose is None and found.forget and found.reason == "stopped"
    assert track.lookup(10 * MS, None, WAIT_S).pose is not None  # where it flowed, it is used


def test_odometry_that_jumps_makes_the_filter_forget_once() -> None:
    """A reset moves the pose 2 m between two messages 20 ms apart while the twist says 1 m/s: the frame
    after it forgets; the next frame has its pose again. A fast drive the twist explains is no jump."""
    track = OdometryTrack()
    driving(track, list(range(0, 100, 20)))
    track.add(OdometrySample(100 * MS, (2.0, 0.0, 0.0), yaw(0.0), (1.0, 0.0, 0.0), (0.0, 0.0, 0.5)))
    track.add(OdometrySample(120 * MS, (2.02, 0.0, 0.0), yaw(0.0), (1.0, 0.0, 0.0), (0.0, 0.0, 0.5)))
    track.add(OdometrySample(140 * MS, (2.04, 0.0, 0.0), yaw(0.0), (1.0, 0.0, 0.0), (0.0, 0.0, 0.5)))
    assert not track.lookup(70 * MS, 37 * MS, WAIT_S).forget
    jumped = track.lookup(103 * MS, 70 * MS, WAIT_S)
    assert jumped.forget and jumped.reason == "jumped" and jumped.pose is None
    after = track.lookup(136 * MS, 103 * MS, WAIT_S)
    assert not after.forget and after.pose is not None
    fast = OdometryTrack()
    driving(fast, list(range(0, 200, 20)), speed=15.0, turn=2.0)  # 0.3 m and 0.04 rad a message
    assert not any(fast.lookup(ms * MS, (ms - 33) * MS, WAIT_S).forget for ms in range(33, 180, 33))


def test_a_stamp_that_goes_back_starts_the_track_anew() -> None:
    track = OdometryTrack()
    driving(track, [1000, 1020, 1040])
    driving(track, [0, 20])  # the bag looped
    assert len(track) == 2
    assert track.lookup(1030 * MS, None, WAIT_S).pose is None
    assert track.lookup(10 * MS, None, WAIT_S).pose is not None


def test_waiting_ends_when_the_message_after_the_stamp_arrives_or_the_wait_runs_out() -> None:
    track = OdometryTrack()
    driving(track, [0])
    later = threading.Timer(0.05, lambda: driving(track, [40]))
    later.start()
    start = time.monotonic()
    assert track.wait_past(30 * MS, 5.0)
    assert time.monotonic() - start < 4.0  # woken by the message, not by the timeout
    assert not track.wait_past(60 * MS, 0.05)
    later.join()
