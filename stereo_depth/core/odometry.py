"""Odometry for the temporal filter: where the robot was at each frame's stamp, and whether that can be trusted.

A robot publishes its motion as nav_msgs/Odometry: the pose of its base (`child_frame_id`) in the odometry
frame, and its twist in the base frame. `OdometryTrack` holds those messages in stamp order (one stream;
thread-safe: the node's subscription adds while its worker looks up) and gives, for a frame's stamp:

- the pose, interpolated between the two messages that bracket the stamp (position linearly, orientation
  by slerp), so that it does not depend on when the messages arrived;
- `late`: no message at or after the stamp yet (a node waits for one up to `odom_wait_seconds`, then
  takes the frame without odometry), or none before it;
- `forget`: the odometry cannot be trusted across this frame, so the filter forgets its history:
  - it stopped: the bracketing messages lie more than the wait apart, or none came after the stamp and
    the last is older than the wait;
  - it jumped: between the previous frame and this one, two consecutive messages differ by a pose change
    the twist cannot explain (`JUMP_METRES` and `JUMP_RADIANS` beyond it, plus half of the twist's own
    motion), as after an odometry reset or a relocalisation that moves the odometry frame.

Stamps are integers in nanoseconds; the lookup is a function of the messages with stamps up to the
bracketing one, so a node and `process` give the same answer once those have arrived. ROS-free.
"""

from __future__ import annotations

import bisect
import threading
import time
from typing import NamedTuple

import cv2
import numpy as np

from stereo_depth.core.pose import pose_matrix

JUMP_METRES = 0.1  # a position change this far beyond what the twist explains is a jump
JUMP_RADIANS = 0.1  # likewise for the orientation
KEEP_NS = 30_000_000_000  # how far back a track keeps messages (the filter's history spans well under a second)
NS = 1e-9


class OdometrySample(NamedTuple):
    """One nav_msgs/Odometry: the base's pose in the odometry frame and its twist in the base frame."""

    stamp_ns: int
    position: tuple[float, float, float]
    orientation: tuple[float, float, float, float]  # unit quaternion x, y, z, w
    linear: tuple[float, float, float] = (0.0, 0.0, 0.0)  # m/s, in the base frame
    angular: tuple[float, float, float] = (0.0, 0.0, 0.0)  # rad/s, in the base frame


class OdometryLookup(NamedTuple):
    """The base's pose at a stamp (4x4 float64, base in the odometry frame; None: not known) and what the
    filter must do about it."""

    pose: np.ndarray | None
    forget: bool = False  # the odometry stopped or jumped: forget the history
    reason: str | None = None  # why, for one log line: "stopped" / "jumped"


class OdometryTrack:
    """The odometry messages of one stream, in stamp order."""

    def __init__(self) -> None:
        self._stamps: list[int] = []
        self._samples: list[OdometrySample] = []
        self._jumps: list[bool] = []  # per message: it jumped from the one before
        self._arrived = threading.Condition()

    def clear(self) -> None:
        with self._arrived:
            self._stamps, self._samples, self._jumps = [], [], []

    def __len__(self) -> int:
        return len(self._stamps)

    def add(self, sample: OdometrySample) -> None:
        """One message. A stamp before the newest starts the track anew (a bag looping, a restarted
        driver); a repeated stamp is ignored."""
        with self._arrived:
            if self._stamps and sample.stamp_ns < self._stamps[-1]:
                self._stamps, self._samples, self._jumps = [], [], []
            if self._stamps and sample.stamp_ns == self._stamps[-1]:
                return
            self._jumps.append(bool(self._samples) and _jumped(self._samples[-1], sample))
            self._stamps.append(sample.stamp_ns)
            self._samples.append(sample)
            old = bisect.bisect_left(self._stamps, sample.stamp_ns - KEEP_NS)
            if old > len(self._stamps) // 2:  # trim in halves: amortised O(1) a message
                del self._stamps[:old], self._samples[:old], self._jumps[:old]
            self._arrived.notify_all()

    def wait_past(self, stamp_ns: int, timeout_s: float) -> bool:
        """Block until a message at or after `stamp_ns` is here, at most `timeout_s`; whether one is."""
        deadline = time.monotonic() + timeout_s
        with self._arrived:
            while not (self._stamps and self._stamps[-1] >= stamp_ns):
                left = deadline - time.monotonic()
                if left <= 0.0:
                    return False
                self._arrived.wait(left)
            return True

    def lookup(self, stamp_ns: int, since_ns: int | None, wait_s: float) -> OdometryLookup:
        """The pose at `stamp_ns`; `since_ns`: the previous frame's stamp (None: none), the start of the
        span checked for jumps; `wait_s`: the longest gap a stream of odometry may have."""
        limit_ns = int(wait_s * 1e9)
        with self._arrived:
            after = bisect.bisect_left(self._stamps, stamp_ns)  # the first message at or after the stamp
            if after == len(self._stamps):
                if self._stamps and stamp_ns - self._stamps[-1] > limit_ns:
                    return OdometryLookup(None, forget=True, reason="stopped")
                return OdometryLookup(None)
            if self._stamps[after] == stamp_ns:
                before = after
            elif after == 0:
                return OdometryLookup(None)
            else:
                before = after - 1
                if self._stamps[after] - self._stamps[before] > limit_ns:
                    return OdometryLookup(None, forget=True, reason="stopped")
            first = after if since_ns is None else bisect.bisect_right(self._stamps, since_ns)
            if any(self._jumps[max(first, 1) : after + 1]):
                return OdometryLookup(None, forget=True, reason="jumped")
            a, b = self._samples[before], self._samples[after]
        share = 0.0 if before == after else (stamp_ns - a.stamp_ns) / (b.stamp_ns - a.stamp_ns)
        return OdometryLookup(
            pose_matrix(_lerp(a.position, b.position, share), _slerp(a.orientation, b.orientation, share))
        )


def _lerp(a: tuple[float, ...], b: tuple[float, ...], share: float) -> np.ndarray:
    start = np.asarray(a, np.float64)
    between: np.ndarray = start + (np.asarray(b, np.float64) - start) * share
    return between


def _slerp(a: tuple[float, ...], b: tuple[float, ...], share: float) -> tuple[float, ...]:
    qa, qb = np.asarray(a, np.float64), np.asarray(b, np.float64)
    qa, qb = qa / np.linalg.norm(qa), qb / np.linalg.norm(qb)
    dot = float(qa @ qb)
    if dot < 0.0:  # the shorter way round
        qb, dot = -qb, -dot
    if dot > 0.9995:  # nearly the same: linear is exact enough and stable
        q = qa + (qb - qa) * share
    else:
        angle = np.arccos(dot)
        q = (np.sin((1.0 - share) * angle) * qa + np.sin(share * angle) * qb) / np.sin(angle)
    return tuple(float(v) for v in q / np.linalg.norm(q))


def _rotation_vector(rotation: np.ndarray) -> np.ndarray:
    """The axis times the angle of a 3x3 rotation."""
    vector, _ = cv2.Rodrigues(rotation)
    return np.asarray(vector, np.float64).reshape(3)


def _jumped(a: OdometrySample, b: OdometrySample) -> bool:
    """Whether b's pose lies further from a's than the twist (the mean of both, in the base frame)
    explains: JUMP_METRES / JUMP_RADIANS plus half the twist's own motion."""
    dt = (b.stamp_ns - a.stamp_ns) * NS
    pose_a, pose_b = pose_matrix(a.position, a.orientation), pose_matrix(b.position, b.orientation)
    relative = np.linalg.inv(pose_a) @ pose_b  # b in a's base frame
    moved = (np.asarray(a.linear) + np.asarray(b.linear)) * 0.5 * dt
    turned = (np.asarray(a.angular) + np.asarray(b.angular)) * 0.5 * dt
    position_error = float(np.linalg.norm(relative[:3, 3] - moved))
    angle_error = float(np.linalg.norm(_rotation_vector(relative[:3, :3]) - turned))
    return bool(
        position_error > JUMP_METRES + 0.5 * float(np.linalg.norm(moved))
        or angle_error > JUMP_RADIANS + 0.5 * float(np.linalg.norm(turned))
    )
