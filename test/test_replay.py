"""Bundled bags replayed over real DDS: into a recorder, and into a running stereo_node.

`stereo-depth replay` and stereo_node run as separate processes; the test process records. The node's
disparity must be bit-identical, frame by frame, to `stereo-depth process` on the same bag.
"""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from ros_helpers import TIMEOUT_S, NodeProcess, RosHarness, wait_until
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image
from stereo_msgs.msg import DisparityImage

from stereo_depth.bag.process import ProcessOptions, process_bag
from stereo_depth.bag.reader import read_messages
from stereo_depth.cli import main
from stereo_depth.core.params import make_params
from stereo_depth.formats.euroc import stereo_camera_infos
from stereo_depth.messages import disparity_from_msg, stamp_to_ns

from conftest import EUROC, euroc_sequence

BAGS = Path(__file__).resolve().parents[1] / "bags"
NS = "/stereo"


def replay(bag: Path, env: dict[str, str], *args: str) -> subprocess.CompletedProcess[str]:
    command = [sys.executable, "-m", "stereo_depth.cli", "replay", str(bag), "--wait-for-subscribers", "1", *args]
    return subprocess.run(command, env=env, capture_output=True, text=True, timeout=120, check=False)


@pytest.fixture(scope="module")
def large_images_env(ros_env: dict[str, str]) -> dict[str, str]:
    """Fast DDS with a shared-memory segment that holds a whole image, as the README tells users.

    Without it, samples over 512 KB (the 512x384 colour frames, every disparity image) travel as UDP
    fragments; a lost fragment is repaired only at the next heartbeat, by which time the synchronizer
    has moved on and the frame is gone.
    """
    profile = str(Path(__file__).resolve().parents[1] / "config" / "fastdds_large_images.xml")
    return {**ros_env, "FASTRTPS_DEFAULT_PROFILES_FILE": profile, "FASTDDS_DEFAULT_PROFILES_FILE": profile}


@pytest.fixture(scope="module")
def stereo_node(
    ros: RosHarness, large_images_env: dict[str, str], tmp_path_factory: pytest.TempPathFactory
) -> Iterator[NodeProcess]:
    node = NodeProcess("stereo_node", NS, large_images_env, tmp_path_factory.mktemp("replay_logs"))
    with ros.running([node]):
        yield node


def test_replay_sends_every_message_unchanged_with_remaps(ros: RosHarness, ros_env: dict[str, str]) -> None:
    bag = BAGS / "euroc_raw"
    topics = [f"{NS}/left/image_raw", f"{NS}/right/image_raw"]
    remaps = [arg for topic in topics for arg in ("--remap", f"{topic}:=/recorded{topic}")]
    collectors = [ros.collector(Image, f"/recorded{topic}") for topic in topics]
    result = replay(bag, ros_env, "--rate", "4", "--topics", *topics, *remaps)
    assert result.returncode == 0, result.stderr
    assert "published 12 messages" in result.stdout
    recorded = read_messages(bag, topics)
    for collector, topic in zip(collectors, topics, strict=True):
        count = len(recorded[topic])
        wait_until(lambda c=collector, n=count: len(c.messages) >= n, f"all of {topic}")
        assert len(collector.messages) == len(recorded[topic])
        for got, sent in zip(collector.messages, recorded[topic], strict=True):
            assert stamp_to_ns(got.header.stamp) == stamp_to_ns(sent.header.stamp)
            assert (got.encoding, got.width, got.height) == (sent.encoding, sent.width, sent.height)
            assert bytes(got.data) == sent.data.tobytes()


def test_replay_plays_a_ros1_bag_as_ros2_messages_with_its_clock(
    ros: RosHarness, ros_env: dict[str, str], tmp_path: Path
) -> None:
    """Jazzy's ros2 bag play cannot read ROS 1 bags; replay sends their messages as Jazzy's, and /clock."""
    bag = tmp_path / "euroc.bag"
    assert main(["make-bag", str(EUROC), str(bag), "--storage", "rosbag1"]) == 0
    topics = [f"{NS}/left/image_raw", f"{NS}/left/camera_info"]
    images, infos = ros.collector(Image, topics[0]), ros.collector(CameraInfo, topics[1])
    clock = ros.collector(Clock, "/clock")
    result = replay(bag, ros_env, "--rate", "4", "--topics", *topics, "--clock", "100")
    assert result.returncode == 0, result.stderr
    expected = read_messages(BAGS / "euroc_raw", topics)  # the same frames as a ROS 2 bag
    wait_until(lambda: len(images.messages) >= 6 and len(infos.messages) >= 6, "every image and camera_info")
    for got, sent in zip(images.messages, expected[topics[0]], strict=True):
        assert stamp_to_ns(got.header.stamp) == stamp_to_ns(sent.header.stamp)
        assert (got.encoding, got.width, got.height, bytes(got.data)) == (
            sent.encoding,
            sent.width,
            sent.height,
            sent.data.tobytes(),
        )
    calibration, _ = stereo_camera_infos(EUROC / "cam0_sensor.yaml", EUROC / "cam1_sensor.yaml")
    for got in infos.messages:
        np.testing.assert_array_equal(np.asarray(got.p), calibration.p.ravel())
        np.testing.assert_array_equal(np.asarray(got.d), calibration.d)
    stamps = [stamp_to_ns(m.header.stamp) for m in images.messages]
    wait_until(lambda: clock.messages and stamp_to_ns(clock.messages[-1].clock) == stamps[-1], "/clock at the end")
    times = [stamp_to_ns(m.clock) for m in clock.messages]
    assert times == sorted(times) and stamps[0] <= times[0] and len(times) > len(stamps)


def test_replay_refuses_a_bad_remap_and_a_missing_topic(ros_env: dict[str, str]) -> None:
    result = replay(BAGS / "euroc_raw", ros_env, "--remap", "nonsense")
    assert result.returncode == 1 and "from:=to" in result.stderr
    result = replay(BAGS / "euroc_raw", ros_env, "--topics", "/nope")
    assert result.returncode == 1 and "/stereo/left/image_raw" in result.stderr


@pytest.mark.parametrize("bag_name", ["euroc_raw", "middlebury"])
def test_stereo_node_on_a_replayed_bag_matches_process(
    bag_name: str, ros: RosHarness, large_images_env: dict[str, str], stereo_node: NodeProcess, tmp_path: Path
) -> None:
    bag = BAGS / bag_name
    collector = ros.collector(DisparityImage, f"{NS}/disparity")
    wait_until(lambda: collector.subscription.get_publisher_count() >= 1, "stereo_node's disparity matched")
    summary = process_bag(bag, tmp_path / "processed", make_params())
    offline = {
        stamp_to_ns(m.header.stamp): disparity_from_msg(m)
        for m in read_messages(tmp_path / "processed", [f"{NS}/disparity"])[f"{NS}/disparity"]
    }
    assert len(offline) == summary.left_images == summary.frames_out

    result = replay(bag, large_images_env)  # 1x: the bag's own timing
    assert result.returncode == 0, result.stderr
    wait_until(lambda: len(collector.stamps()) >= len(offline), f"{len(offline)} disparity frames", TIMEOUT_S)
    assert sorted(collector.stamps()) == sorted(offline), stereo_node.output()
    for message in collector.messages:
        live = disparity_from_msg(message)
        np.testing.assert_array_equal(live, offline[stamp_to_ns(message.header.stamp)])
    ros.node.destroy_subscription(collector.subscription)


def test_stereo_node_with_the_temporal_filter_matches_process_on_30_frames(
    ros: RosHarness, large_images_env: dict[str, str], tmp_path: Path
) -> None:
    """The filter's state, live and offline: the same 30 frames of a moving camera give the same
    filtered disparity bit for bit (a stereo_node of its own, fed through remaps)."""
    bag = tmp_path / "euroc30"
    assert main(["make-bag", str(euroc_sequence(tmp_path / "sequence", 30)), str(bag), "--rate", "10"]) == 0
    # the view jumps (the EuRoC frames looped): the ego-motion test would make the filter stand aside
    filtering = {"temporal_filter": True, "temporal_ego_motion": 0.0}
    params, options = make_params("default", filtering), ProcessOptions(outputs=("disparity",))
    summary = process_bag(bag, tmp_path / "processed", params, options)
    offline = {
        stamp_to_ns(m.header.stamp): disparity_from_msg(m)
        for m in read_messages(tmp_path / "processed", [f"{NS}/disparity"])[f"{NS}/disparity"]
    }
    assert len(offline) == summary.frames_out == 30
    persistence = params.temporal_persistence
    assert sum(np.isnan(d).all() for d in offline.values()) == persistence - 1  # nothing before frames agree

    namespace = "/temporal"
    # A frame lost on a busy machine would change every filtered frame after it: queues hold them all, and
    # 2.5 frames/s keeps the node ahead of its input even with a second test file and a busy core beside it.
    args = ["-p", "temporal_filter:=true", "-p", "temporal_ego_motion:=0.0", "-p", "max_waiting_frames:=30"]
    args += ["-p", "queue_size:=30"]
    node = NodeProcess("stereo_node", namespace, large_images_env, tmp_path, args)
    with ros.running([node]):
        collector = ros.collector(DisparityImage, f"{namespace}/disparity")
        wait_until(lambda: collector.subscription.get_publisher_count() >= 1, "stereo_node's disparity matched")
        inputs = ("left/image_raw", "left/camera_info", "right/image_raw", "right/camera_info")
        remaps = [arg for topic in inputs for arg in ("--remap", f"{NS}/{topic}:={namespace}/{topic}")]
        result = replay(bag, large_images_env, "--rate", "0.25", *remaps)
        assert result.returncode == 0, result.stderr
        wait_until(lambda: len(collector.stamps()) >= len(offline), f"{len(offline)} disparity frames", 2 * TIMEOUT_S)
        assert sorted(collector.stamps()) == sorted(offline), node.output()
        for message in collector.messages:
            np.testing.assert_array_equal(disparity_from_msg(message), offline[stamp_to_ns(message.header.stamp)])
        ros.node.destroy_subscription(collector.subscription)
