"""The temporal filter's odometry live: stereo_node with left_in_base reads odom and filters a pitching
camera's frames as `process` does, bit for bit; where the odometry stops it says so once and goes on; the
lifecycle node reads odom only while active, from a best-effort publisher too.
"""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
from lifecycle_msgs.msg import Transition
from nav_msgs.msg import Odometry
from odometry_bag import NS, ODOM, STEREO_TOPICS, left_in_base_text, write_odometry_bag
from rclpy.qos import ReliabilityPolicy
from ros_helpers import TIMEOUT_S, NodeProcess, RosHarness, wait_until
from stereo_msgs.msg import DisparityImage
from test_lifecycle_node import NODE, Managed
from test_qos_overrides import subscription_reliability

from stereo_depth.bag.reader import read_messages
from stereo_depth.cli import main
from stereo_depth.messages import disparity_from_msg, stamp_to_ns

FRAMES = 30
FILTER = {"temporal_filter": "true", "left_in_base": left_in_base_text()}
# A frame lost on a busy machine would change every filtered frame after it: queues hold them all.
QUEUES = ["-p", f"max_waiting_frames:={FRAMES}", "-p", f"queue_size:={FRAMES}"]


def offline(bag: Path, out: Path, values: dict[str, str]) -> dict[int, np.ndarray]:
    """`process` of the bag: {stamp: disparity}."""
    sets = [arg for name, value in values.items() for arg in ("--set", f"{name}={value}")]
    assert main(["process", str(bag), str(out), *sets, "--outputs", "disparity"]) == 0
    messages = read_messages(out, [f"{NS}/disparity"])[f"{NS}/disparity"]
    return {stamp_to_ns(m.header.stamp): disparity_from_msg(m) for m in messages}


def node_args(values: dict[str, str]) -> list[str]:
    return [*(arg for name, value in values.items() for arg in ("-p", f"{name}:={value}")), *QUEUES]


def replay(bag: Path, env: dict[str, str], rate: float) -> None:
    command = [sys.executable, "-m", "stereo_depth.cli", "replay", str(bag), "--rate", str(rate)]
    command += ["--wait-for-subscribers", "1", "--topics", *STEREO_TOPICS, ODOM]
    done = subprocess.run(command, env=env, capture_output=True, text=True, timeout=180, check=False)
    assert done.returncode == 0, done.stderr


def live(
    ros: RosHarness, node: NodeProcess, bag: Path, env: dict[str, str], rate: float, last_ns: int
) -> dict[int, np.ndarray]:
    """The node's disparity of the bag replayed at `rate`, up to the frame at `last_ns`: {stamp: disparity}."""
    with ros.running([node]):
        collector = ros.collector(DisparityImage, f"{NS}/disparity")
        wait_until(lambda: collector.subscription.get_publisher_count() >= 1, "stereo_node's disparity matched")
        replay(bag, env, rate)
        wait_until(lambda: last_ns in collector.stamps(), "the last frame's disparity", 2 * TIMEOUT_S)
        found = {stamp_to_ns(m.header.stamp): disparity_from_msg(m) for m in collector.messages}
        ros.node.destroy_subscription(collector.subscription)
    return found


def test_the_node_moves_the_history_by_odometry_as_process_does_bit_for_bit(
    ros: RosHarness, ros_env: dict[str, str], tmp_path: Path
) -> None:
    bag = tmp_path / "pitching"
    stamps = write_odometry_bag(bag, FRAMES)
    values = {**FILTER, "odom_wait_seconds": "0.5"}  # a busy machine's odometry is never later than that
    expected = offline(bag, tmp_path / "offline", values)
    without = offline(bag, tmp_path / "without", {"temporal_filter": "true"})
    assert len(expected) == FRAMES
    assert any(not np.array_equal(expected[s], without[s], equal_nan=True) for s in expected)  # odometry counts
    node = NodeProcess("stereo_node", NS, ros_env, tmp_path, node_args(values))
    found = live(ros, node, bag, ros_env, 0.25, stamps[-1])
    assert sorted(found) == sorted(expected), node.output()
    for stamp, disparity in found.items():
        np.testing.assert_array_equal(disparity, expected[stamp], err_msg=f"frame {stamp}")


def test_odometry_that_stops_gives_one_log_line_and_the_frames_keep_coming(
    ros: RosHarness, ros_env: dict[str, str], tmp_path: Path
) -> None:
    bag = tmp_path / "stops"
    stamps = write_odometry_bag(bag, FRAMES, odometry_until_s=0.4)
    node = NodeProcess("stereo_node", NS, ros_env, tmp_path, node_args(FILTER))
    found = live(ros, node, bag, ros_env, 0.5, stamps[-1])
    # a loaded machine's node drops frames while it falls behind (never the newest); the rule is that
    # frames keep coming after the odometry stopped, and half of those is plenty to show it
    after = [stamp for stamp in stamps if stamp > stamps[0] + 400_000_000]
    assert len(set(after) & set(found)) >= len(after) // 2, f"{len(found)} of {FRAMES} frames"
    lines = [line for line in node.output().splitlines() if "odometry stopped" in line]
    assert len(lines) == 1 and ODOM in lines[0], node.output()
    last = [found[stamp] for stamp in sorted(found)[-5:]]
    assert all(np.isfinite(d).mean() > 0.5 for d in last)  # filtered without odometry, not emptied


def test_the_lifecycle_node_reads_odom_only_while_active_following_a_best_effort_publisher(
    ros: RosHarness, start_node: Callable[..., NodeProcess]
) -> None:
    ns = "/odom_cycle"
    managed = Managed(ros, start_node(NODE, ns, ["-p", f"left_in_base:={left_in_base_text()}"]))
    odometry = ros.publisher(Odometry, f"{ns}/odom", ReliabilityPolicy.BEST_EFFORT)  # as many robot drivers
    try:
        assert managed.change(Transition.TRANSITION_CONFIGURE)
        assert managed.subscriptions("odom") == 0
        for activation in ("first", "second"):
            assert managed.change(Transition.TRANSITION_ACTIVATE)
            wait_until(
                lambda: subscription_reliability(ros, f"{ns}/odom", NODE) == ReliabilityPolicy.BEST_EFFORT,
                f"odom subscribed best effort after the {activation} activation",
            )
            assert managed.change(Transition.TRANSITION_DEACTIVATE)
            wait_until(lambda: managed.subscriptions("odom") == 0, f"odom released after the {activation}")
    finally:
        ros.node.destroy_publisher(odometry)
