"""`stereo-depth check-calibration`: does a bag's stereo calibration still hold? Per-frame row offsets."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from stereo_depth.commands.common import add_topic_options, topic_choice
from stereo_depth.core.calibration_check import CalibrationCheck, Level, check_rectified_pair, verdict
from stereo_depth.errors import CalibrationError

if TYPE_CHECKING:
    from stereo_depth.bag.reader import TopicChoice


def add_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    parser = sub.add_parser(
        "check-calibration",
        help="measure the vertical offset of feature matches after rectification, frame by frame",
        description=(
            "Rectifies each stereo frame of IN_BAG (ROS 1 or ROS 2) with its camera_info (or --camera-info), matches "
            "features between left and right and prints the median vertical offset of the RANSAC inliers. "
            "The verdict is the median over the frames that could be judged: OK below 0.5 px, WARN from "
            "0.5 px, ERROR above 1.5 px. Exit status: 0 OK, 1 WARN or a usage error, 2 ERROR, 3 no frame "
            "could be judged."
        ),
    )
    parser.add_argument("in_bag", type=Path, metavar="IN_BAG")
    add_topic_options(parser)
    parser.add_argument("--every", type=int, default=1, metavar="N", help="check every Nth frame (default 1)")
    parser.set_defaults(run=run)


def check_bag(path: Path, choice: TopicChoice, every: int) -> list[tuple[int, CalibrationCheck]]:
    """(stamp, check) for every Nth frame, rectified the way stereo_node rectifies it."""
    from stereo_depth.bag.reader import StereoBagReader  # rosbags only when a bag is read
    from stereo_depth.core.pipeline import StereoPipeline
    from stereo_depth.frames import decode_frame
    from stereo_depth.options import OutputOptions

    results = []
    pipeline = StereoPipeline()  # only its calibration cache is used: one StereoCamera per calibration
    with StereoBagReader(path, choice=choice) as reader:
        rectified, names = reader.topics.rectified, reader.topics.input_names
        for index, inputs in enumerate(reader.frames()):
            if index % every:
                continue
            frame = decode_frame(inputs, pipeline, OutputOptions(), rectified=rectified, names=names)
            left, right = frame.left, frame.right
            assert right is not None
            if not rectified:
                left, right = frame.camera.rectify(left, "left"), frame.camera.rectify(right, "right")
            results.append((inputs.stamp_ns, check_rectified_pair(left, right)))
    return results


def overall(results: list[tuple[int, CalibrationCheck]]) -> tuple[Level, str]:
    """The median offset over the frames that had enough matches to be judged."""
    judged = [check for _, check in results if check.level != Level.STALE]
    if not judged:
        return Level.STALE, f"none of {len(results)} frames had enough feature matches to judge the calibration"
    median = float(np.median([c.median_dy for c in judged]))
    level, message = verdict(median, sum(c.inliers for c in judged))
    return level, f"{len(judged)} of {len(results)} frames judged; {message}"


def run(args: argparse.Namespace) -> int:
    if args.every < 1:
        msg = f"--every {args.every} must be at least 1"
        raise CalibrationError(msg)
    results = check_bag(args.in_bag, topic_choice(args), args.every)
    if not results:
        msg = f"{args.in_bag}: no complete stereo frame to check"
        raise CalibrationError(msg)
    print(f"{'stamp_ns':>20s} {'dy_px':>7s} {'inliers':>7s}  level")
    for stamp, check in results:
        print(f"{stamp:20d} {check.median_dy:7.3f} {check.inliers:7d}  {check.level.name}")
    level, message = overall(results)
    print(f"verdict: {level.name}: {message}")
    return int(level)
