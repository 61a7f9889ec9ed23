"""Depth registered to a colour camera, live: stereo_node with rgb_in_left publishes what `process` writes,
bit for bit, on a 20-frame bag whose colour camera is stamped 3 ms after the stereo pair; and its bad
inputs cost only the registered outputs, each with one line naming what to fix.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
from colour_bag import COLOUR_TOPICS, NS, STEREO_TOPICS, cam1_in_cam0, write_colour_bag
from rclpy.serialization import deserialize_message
from ros_helpers import NodeProcess, RosHarness, wait_until
from sensor_msgs.msg import Image

from stereo_depth.bag.recording import open_reader
from stereo_depth.cli import main
from stereo_depth.core.camera import CameraInfo

FRAMES = 20


def pose_text() -> str:
    return "[" + ", ".join(f"{v:.17g}" for v in cam1_in_cam0()) + "]"


def offline(bag: Path, out: Path, outputs: tuple[str, ...]) -> dict[str, dict[int, Any]]:
    """`process` of the bag with the same pose: {output: {stamp: rclpy message}}."""
    assert main(["process", str(bag), str(out), "--set", f"rgb_in_left={pose_text()}", "--outputs", *outputs]) == 0
    found: dict[str, dict[int, Any]] = {name: {} for name in outputs}
    reader = open_reader(out)
    try:
        for connection, log_time, raw in reader.messages(reader.connections):
            found[connection.topic.removeprefix(f"{NS}/")][log_time] = deserialize_message(bytes(raw), Image)
    finally:
        reader.close()
    return found


def replay(bag: Path, ros_env: dict[str, str], topics: tuple[str, ...]) -> None:
    """The bag at a quarter of its speed (a busy machine's node keeps up with every frame)."""
    command = [sys.executable, "-m", "stereo_depth.cli", "replay", str(bag), "--rate", "0.25"]
    command += ["--wait-for-subscribers", "1", "--topics", *topics]
    done = subprocess.run(command, env=ros_env, capture_output=True, text=True, timeout=180, check=False)
    assert done.returncode == 0, done.stderr


def test_the_node_registers_what_process_writes_bit_for_bit(
    ros: RosHarness, ros_env: dict[str, str], tmp_path: Path
) -> None:
    bag = tmp_path / "colour"
    stamps = write_colour_bag(bag, FRAMES)
    expected = offline(bag, tmp_path / "offline", ("depth", "depth_registered/image_rect"))
    assert sorted(expected["depth_registered/image_rect"]) == sorted(stamps.values())  # each colour image, its stamp
    args = ["-p", f"rgb_in_left:={pose_text()}", "-p", f"max_waiting_frames:={FRAMES}"]
    node = NodeProcess("stereo_node", NS, ros_env, tmp_path, args)
    with ros.running([node]):
        collectors = {name: ros.collector(Image, f"{NS}/{name}") for name in expected}
        for name, collector in collectors.items():
            wait_until(lambda c=collector: c.subscription.get_publisher_count() >= 1, f"{name} matched")
        replay(bag, ros_env, (*STEREO_TOPICS, *COLOUR_TOPICS))
        for name, collector in collectors.items():
            # the last colour image is decided once the stereo inputs pause (5 s), as at the end of the bag
            last = max(expected[name])
            wait_until(lambda c=collector, t=last: t in c.stamps(), f"the last frame of {name}", 60.0)
            live = dict(zip(collector.stamps(), collector.messages, strict=True))
            # a loaded machine may lose the first frames while the node's subscriptions still match replay
            assert len(live) >= FRAMES - 2, f"{name}: {len(live)} of {FRAMES} frames"
            assert live == {stamp: expected[name][stamp] for stamp in live}, f"{name} differs"


def test_a_colour_camera_info_without_focal_length_costs_only_the_registered_outputs(
    ros: RosHarness, ros_env: dict[str, str], tmp_path: Path
) -> None:
    bag = tmp_path / "uncalibrated"
    zero = np.zeros((3, 3))
    stamps = write_colour_bag(bag, 4, colour=CameraInfo.from_values(752, 480, zero, [], zero, np.zeros((3, 4))))
    args = ["-p", f"rgb_in_left:={pose_text()}", "-p", "max_waiting_frames:=10"]
    node = NodeProcess("stereo_node", NS, ros_env, tmp_path, args)
    with ros.running([node]):
        depth = ros.collector(Image, f"{NS}/depth")
        registered = ros.collector(Image, f"{NS}/depth_registered/image_rect")
        wait_until(lambda: registered.subscription.get_publisher_count() >= 1, "registered depth matched")
        replay(bag, ros_env, (*STEREO_TOPICS, *COLOUR_TOPICS))
        wait_until(lambda: "no focal length" in node.output(), "the log line", 60.0)
        # depth goes on (a frame may be dropped on a busy machine, never all of them)
        wait_until(lambda: len(depth.messages) >= len(stamps) - 1, "the frames' depth", 60.0)
        assert registered.messages == []
    line = next(line for line in node.output().splitlines() if "no focal length" in line)
    assert f"{NS}/rgb/camera_info" in line


def test_a_registered_output_subscribed_without_rgb_in_left_names_the_parameter(
    ros: RosHarness, ros_env: dict[str, str], tmp_path: Path
) -> None:
    node = NodeProcess("stereo_node", NS, ros_env, tmp_path)
    with ros.running([node]):
        ros.collector(Image, f"{NS}/depth_registered/image_rect")
        wait_until(lambda: "rgb_in_left" in node.output(), "a line naming rgb_in_left", 30.0)
    assert "depth_registered/image_rect need the colour camera's pose: set rgb_in_left" in node.output()


def test_a_quaternion_that_is_not_normalised_is_refused_at_start_up(ros_env: dict[str, str], tmp_path: Path) -> None:
    node = NodeProcess("stereo_node", NS, ros_env, tmp_path, ["-p", "rgb_in_left:=[0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 2.0]"])
    code = node.process.wait(timeout=60)
    assert code != 0
    assert "rgb_in_left" in node.output() and "norm 2.0000" in node.output()
