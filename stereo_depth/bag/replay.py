"""Publish a bag over DDS with its original timing, as `ros2 bag play` would, without a ROS install.

Messages go out as the CDR bytes stored in the bag (rclpy publishes `bytes` as they are), so nothing
is deserialized on the way. rclpy is imported inside the functions: the rest of bag/ must work where
only rosbags is installed.
"""

from __future__ import annotations

import importlib
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
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
    sent = 0
    try:
        _wait_for_subscribers(publishers, options.wait_for_subscribers, options.wait_timeout)
        while True:
            for _ in _play_once(path, wanted, publishers, options.rate):
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


def _play_once(path: Path, wanted: set[str] | None, publishers: dict[str, Any], rate: float) -> Iterator[str]:
    """One pass over the bag, each message at its recorded offset from the first, divided by `rate`."""
    _, messages = _timeline(path, wanted)
    start_wall = time.monotonic()
    first: int | None = None
    for topic, timestamp, raw in messages:
        first = timestamp if first is None else first
        delay = start_wall + (timestamp - first) / 1e9 / rate - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        publishers[topic].publish(raw)
        yield topic
