"""Publish a bag over DDS with its original timing, as `ros2 bag play` would, without a ROS install.

Messages go out as the CDR bytes stored in the bag (rclpy publishes `bytes` as they are), so nothing
is deserialized on the way; a ROS 1 bag's messages are turned into Jazzy's CDR first (bag/recording.py),
which Jazzy's `ros2 bag play` cannot do at all. Compressed image topics go out as they are. `clock`
publishes the bag's time on /clock, as `ros2 bag play --clock`, for nodes run with use_sim_time.
rclpy is imported inside the functions: the rest of bag/ must work where only rosbags is installed.
"""

from __future__ import annotations

import importlib
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

from stereo_depth.bag.recording import open_reader
from stereo_depth.errors import BagError

QOS_DEPTH = 10


@dataclass
class ReplayOptions:
    rate: float = 1.0
    loop: bool = False
    topics: list[str] | None = None  # None: every topic in the bag
    remaps: list[str] = field(default_factory=list)  # ROS remapping rules, from:=to
    wait_for_subscribers: int = 0  # on every published topic, before the first message
    wait_timeout: float = 10.0  # seconds
    clock_hz: float = 0.0  # > 0: publish the bag's time on /clock this often (and before every message)


def message_class(msgtype: str) -> Any:
    """The rclpy class for 'pkg/msg/Name'; the error names the package to install."""
    package, _, name = msgtype.rpartition("/")
    module_name = package.replace("/", ".")
    try:
        return getattr(importlib.import_module(module_name), name)
    except (ImportError, AttributeError) as exc:
        msg = f"message type {msgtype} is not installed for rclpy; install the package that provides {module_name}"
        raise BagError(msg) from exc


def check_remaps(remaps: list[str]) -> None:
    for rule in remaps:
        source, sep, target = rule.partition(":=")
        if not sep or not source or not target:
            msg = f"--remap expects from:=to, got '{rule}'"
            raise BagError(msg)


def _timeline(path: Path, topics: set[str] | None) -> tuple[list[tuple[str, str]], Iterator[tuple[str, int, bytes]]]:
    """(topic, msgtype) pairs to publish and the messages as (topic, bag time, raw CDR)."""
    reader = open_reader(path)
    connections = [c for c in reader.connections if topics is None or c.topic in topics]
    if topics is not None and (missing := topics - {c.topic for c in connections}):
        have = ", ".join(sorted({c.topic for c in reader.connections}))
        reader.close()
        msg = f"{path} has no topic {', '.join(sorted(missing))}; it has: {have}"
        raise BagError(msg)

    def messages() -> Iterator[tuple[str, int, bytes]]:
        try:
            for connection, timestamp, raw in reader.messages(connections=connections):
                yield connection.topic, timestamp, bytes(raw)
        finally:
            reader.close()

    return sorted({(c.topic, c.msgtype) for c in connections}), messages()


def replay(path: Path | str, options: ReplayOptions | None = None) -> int:
    """Publish the bag (again and again with `loop`); returns the number of messages sent."""
    import rclpy
    from rclpy.context import Context
    from rclpy.duration import Duration
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

    options = options or ReplayOptions()
    if not options.rate > 0:
        msg = f"--rate {options.rate} must be positive"
        raise BagError(msg)
    if options.clock_hz < 0:
        msg = f"--clock {options.clock_hz} must be a positive rate in Hz"
        raise BagError(msg)
    check_remaps(options.remaps)
    path = Path(path)
    wanted = set(options.topics) if options.topics else None
    topic_types, _ = _timeline(path, wanted)  # fail on a bad bag before DDS starts
    args = ["--ros-args", *(a for rule in options.remaps for a in ("-r", rule))]
    context = Context()
    rclpy.init(args=args, context=context)
    node = rclpy.create_node("stereo_depth_replay", context=context)
    qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=QOS_DEPTH, reliability=ReliabilityPolicy.RELIABLE)
    publishers = {topic: node.create_publisher(message_class(t), topic, qos) for topic, t in topic_types}
    clock = SimClock(node, options.clock_hz) if options.clock_hz > 0 else None
    sent = 0
    try:
        _wait_for_subscribers(publishers, options.wait_for_subscribers, options.wait_timeout)
        while True:
            for _ in _play_once(path, wanted, publishers, options.rate, clock):
                sent += 1
            if not options.loop:
                break
        for publisher in publishers.values():
            publisher.wait_for_all_acked(Duration(seconds=options.wait_timeout))
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    return sent


def _wait_for_subscribers(publishers: dict[str, Any], count: int, timeout: float) -> None:
    """Hold the first message until `count` subscribers matched every topic, so none is lost."""
    if count <= 0:
        return
    deadline = time.monotonic() + timeout
    while True:
        waiting = [p.topic_name for p in publishers.values() if p.get_subscription_count() < count]
        if not waiting:
            return
        if time.monotonic() > deadline:
            msg = (
                f"after {timeout:.0f} s, {', '.join(waiting)} still has fewer than {count} subscriber(s); "
                "start the subscriber, check ROS_DOMAIN_ID and remaps, or lower --wait-for-subscribers"
            )
            raise BagError(msg)
        time.sleep(0.02)


class SimClock:
    """/clock (rosgraph_msgs/Clock) at the bag's time: at a steady rate while waiting for the next
    message and right before each one, so a use_sim_time node never sees a message from its future."""

    def __init__(self, node: Any, hz: float) -> None:
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from rosgraph_msgs.msg import Clock

        self._clock_type = Clock
        qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
        self._publisher = node.create_publisher(Clock, "/clock", qos)
        self.period_s = 1.0 / hz

    def publish(self, bag_ns: int) -> None:
        from builtin_interfaces.msg import Time

        sec, nanosec = divmod(int(bag_ns), 1_000_000_000)
        self._publisher.publish(self._clock_type(clock=Time(sec=sec, nanosec=nanosec)))

    def wait_until(self, deadline: float, bag_ns_at: Callable[[float], int]) -> None:
        """Sleep until the monotonic `deadline`, publishing the bag time every period meanwhile."""
        while (left := deadline - time.monotonic()) > 0:
            time.sleep(min(left, self.period_s))
            self.publish(bag_ns_at(min(time.monotonic(), deadline)))


def _bag_time(first_ns: int, start_wall: float, rate: float, now: float) -> int:
    return first_ns + round((now - start_wall) * rate * 1e9)


def _play_once(
    path: Path, wanted: set[str] | None, publishers: dict[str, Any], rate: float, clock: SimClock | None = None
) -> Iterator[str]:
    """One pass over the bag, each message at its recorded offset from the first, divided by `rate`."""
    _, messages = _timeline(path, wanted)
    start_wall = time.monotonic()
    first: int | None = None
    for topic, timestamp, raw in messages:
        if first is None:
            first = timestamp
        deadline = start_wall + (timestamp - first) / 1e9 / rate
        if clock is not None:
            clock.wait_until(deadline, partial(_bag_time, first, start_wall, rate))
            clock.publish(timestamp)
        elif (delay := deadline - time.monotonic()) > 0:
            time.sleep(delay)
        publishers[topic].publish(raw)
        yield topic
