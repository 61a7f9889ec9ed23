"""What one wake of rclpy's standard executor costs stereo_node, against a node of the same shape with rclpy's
default event handlers.

Each time the executor wakes (an input message, a timer) it rebuilds its wait set in Python from every
subscription, timer, service, guard condition and QoS-event handler of the node, holding the GIL, and a
frame wakes it about three times. rclpy gives every publisher two event handlers unless told otherwise;
stereo_node's outputs carry none (stereo_depth/ros/qos.py: SubscriberWatch looks at the graph for
incompatible subscribers instead) and its inputs one, for lost messages (AdaptiveSubscription polls for
publishers, and for those of another type); rclpy's own /parameter_events publisher keeps its two. The
twin node here has the same publishers, subscriptions and timers with rclpy's default handlers, plus the
lost-message one on each subscription: the baseline, in the same process and run. Each is timed alone
with an executor of its own, `spin_once(timeout_sec=0)` with nothing ready, in alternating batches; the
medians are printed.

    .venv/bin/python bench/executor_wake.py [--batches 10] [--spins 200] [--markdown]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import rclpy
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from stereo_depth.nodes.stereo_node import StereoNode

sys.path.insert(0, str(Path(__file__).parent))
from markdown_table import parse_bench_arguments, table_header, table_row, times


def twin_with_rclpy_defaults(node: Node) -> Node:
    """A node in another namespace with `node`'s publishers, subscriptions and timers, its publishers on
    rclpy's default event handlers."""
    twin = rclpy.create_node(f"{node.get_name()}_twin", namespace="/twin")
    for publisher in node.publishers:
        if not publisher.topic_name.endswith("/parameter_events"):  # every node has its own
            twin.create_publisher(publisher.msg_type, f"/twin{publisher.topic_name}", publisher.qos_profile)
    for subscription in node.subscriptions:
        events = SubscriptionEventCallbacks(message_lost=lambda _info: None)  # and rclpy's defaults
        twin.create_subscription(
            subscription.msg_type,
            f"/twin{subscription.topic_name}",
            lambda _msg: None,
            subscription.qos_profile,
            event_callbacks=events,
        )
    for timer in node.timers:
        twin.create_timer(timer.timer_period_ns / 1e9, lambda: None)
    return twin


def wake_us(executor: SingleThreadedExecutor, spins: int) -> float:
    start = time.perf_counter()
    for _ in range(spins):
        executor.spin_once(timeout_sec=0)
    return (time.perf_counter() - start) / spins * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batches", type=int, default=10, help="timed batches of each node; medians printed")
    parser.add_argument("--spins", type=int, default=200, help="spin_once calls a batch")
    args = parse_bench_arguments(parser)
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    rclpy.init(args=["--ros-args", "-r", "__ns:=/wake", "-p", "profile:=stereo_image_proc"])
    ours = StereoNode()
    twin = twin_with_rclpy_defaults(ours)
    nodes = {"stereo_node": ours, "same entities, rclpy's default event handlers": twin}
    executors = {}
    for label, node in nodes.items():
        executors[label] = SingleThreadedExecutor()
        executors[label].add_node(node)
    try:
        for executor in executors.values():  # warm-up: first wait sets, start-up callbacks
            wake_us(executor, args.spins)
        batches: dict[str, list[float]] = {label: [] for label in nodes}
        for _ in range(args.batches):
            for label, executor in executors.items():
                batches[label].append(wake_us(executor, args.spins))
        columns = ("node", "subscriptions", "timers", "services", "event handlers", "us a wake", "vs rclpy's defaults")
        print(table_header(columns) if args.markdown else "  ".join(columns))
        baseline = statistics.median(batches[list(nodes)[1]])
        for label, node in nodes.items():
            us = statistics.median(batches[label])
            counts = (len(list(getattr(node, kind))) for kind in ("subscriptions", "timers", "services", "waitables"))
            cells = (label, *counts, f"{us:.0f}", times(us / baseline))
            print(table_row(cells) if args.markdown else "  ".join(str(c) for c in cells))
    finally:
        for label, executor in executors.items():
            executor.remove_node(nodes[label])
        for node in nodes.values():
            node.destroy_node()
        rclpy.shutdown()


if __name__ == "__main__":
    main()
