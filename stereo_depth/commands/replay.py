"""`stereo-depth replay`: publish a bag over DDS with its original timing (like `ros2 bag play`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from stereo_depth.bag.replay import ReplayOptions, replay


def add_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    parser = sub.add_parser(
        "replay",
        help="publish a bag's messages over DDS with their recorded timing",
        description=(
            "Publishes every message (raw CDR) of a rosbag2 folder or a ROS 1 .bag file on its recorded topic "
            "with reliable QoS, depth 10; ROS 1 messages are converted to their ROS 2 Jazzy form."
        ),
    )
    parser.add_argument("in_bag", type=Path, metavar="IN_BAG")
    parser.add_argument(
        "--rate", type=float, default=1.0, help="speed factor: 2 plays twice as fast (default %(default)s)"
    )
    parser.add_argument("--loop", action="store_true", help="start again at the end until Ctrl-C")
    parser.add_argument("--topics", nargs="+", metavar="TOPIC", help="publish only these topics")
    parser.add_argument("--remap", action="append", default=[], metavar="FROM:=TO", help="rename a topic (repeatable)")
    parser.add_argument(
        "--wait-for-subscribers",
        type=int,
        default=0,
        metavar="N",
        help="before the first message, wait until every topic has N subscribers (default %(default)s: don't wait)",
    )
    parser.add_argument(
        "--wait-timeout", type=float, default=10.0, metavar="SECONDS", help="give up waiting after this long"
    )
    parser.add_argument(
        "--clock",
        type=float,
        nargs="?",
        const=40.0,
        default=0.0,
        metavar="HZ",
        help="publish the bag's time on /clock (default 40 Hz, as ros2 bag play --clock) for use_sim_time nodes",
    )
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    options = ReplayOptions(
        rate=args.rate,
        loop=args.loop,
        topics=args.topics,
        remaps=args.remap,
        wait_for_subscribers=args.wait_for_subscribers,
        wait_timeout=args.wait_timeout,
        clock_hz=args.clock,
    )
    sent = replay(args.in_bag, options)
    print(f"published {sent} messages from {args.in_bag}")
    return 0
