"""stereo_node on a camera as robots record it, over real DDS: JPEG `image_raw/compressed` topics
(`image_transport:=compressed`) and the calibration from camera_info files (`*_camera_info_url`), no
camera_info topics at all. The node's disparity must equal `process` on a bag of the very same bytes;
a damaged JPEG costs its frame and nothing else."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from ros_helpers import NodeProcess, RosHarness, wait_until
from sensor_msgs.msg import CompressedImage
from stereo_msgs.msg import DisparityImage

from stereo_depth.bag.process import ProcessOptions, process_bag
from stereo_depth.bag.reader import TopicChoice, read_messages
from stereo_depth.bag.sources import read_frames
from stereo_depth.bag.types import rosbags_types
from stereo_depth.bag.writer import BagWriter
from stereo_depth.core.params import make_params
from stereo_depth.formats.camera_info_yaml import camera_info_to_yaml
from stereo_depth.formats.euroc import stereo_camera_infos
from stereo_depth.messages import array_to_compressed, disparity_from_msg, make_header, stamp_to_ns
from stereo_depth.ros.types import RCLPY_TYPES

from conftest import EUROC

NS = "/robot"
DAMAGED = 2  # index of the frame whose left JPEG is cut off in transport
CALIBRATION = stereo_camera_infos(EUROC / "cam0_sensor.yaml", EUROC / "cam1_sensor.yaml")


def jpeg_frames() -> list[tuple[int, Any, Any]]:
    """(stamp, left, right) rclpy CompressedImages of the bundled EuRoC frames; one left one damaged."""
    out = []
    for index, frame in enumerate(read_frames([EUROC])):
        stamp = int(frame.stamp_ns or 0)
        left, right = (
            array_to_compressed(RCLPY_TYPES, make_header(RCLPY_TYPES, stamp, frame_id), pixels, "jpeg")
            for frame_id, pixels in (("cam0", frame.left), ("cam1", frame.right))
        )
        if index == DAMAGED:
            left.data = left.data[: len(left.data) // 2]
        out.append((stamp, left, right))
    return out


def offline(frames: list[tuple[int, Any, Any]], folder: Path) -> dict[int, np.ndarray]:
    """`process` on a bag holding the same bytes, calibrated from the same files."""
    types = rosbags_types()
    with BagWriter(folder / "jpeg") as writer:
        for stamp, *images in frames:
            for side, image in zip(("left", "right"), images, strict=True):
                header = make_header(types, stamp, image.header.frame_id)
                data = np.frombuffer(bytes(image.data), np.uint8)
                message = types.CompressedImage(header=header, format=image.format, data=data)
                writer.write(f"{NS}/{side}/image_raw/compressed", message, stamp)
    options = ProcessOptions(topics=TopicChoice(calibration=CALIBRATION), outputs=("disparity",))
    summary = process_bag(folder / "jpeg", folder / "out", make_params(), options)
    assert summary.frames_out == len(frames) - 1 and "damaged JPEG" in next(iter(summary.skipped))
    messages = read_messages(folder / "out", [f"{NS}/disparity"])[f"{NS}/disparity"]
    return {stamp_to_ns(m.header.stamp): disparity_from_msg(m) for m in messages}


@pytest.fixture(scope="module")
def node(ros: RosHarness, ros_env: dict[str, str], tmp_path_factory: pytest.TempPathFactory) -> Iterator[NodeProcess]:
    folder = tmp_path_factory.mktemp("calibration")
    for side, info in zip(("left", "right"), CALIBRATION, strict=True):
        (folder / f"{side}.yaml").write_text(camera_info_to_yaml(info, side))
    profile = str(Path(__file__).resolve().parents[1] / "config" / "fastdds_large_images.xml")
    env = {**ros_env, "FASTRTPS_DEFAULT_PROFILES_FILE": profile, "FASTDDS_DEFAULT_PROFILES_FILE": profile}
    args = ["-p", "image_transport:=compressed", "-p", "publish_points:=false", "-p", "calibration_check:=false"]
    args += [
        arg for side in ("left", "right") for arg in ("-p", f"{side}_camera_info_url:=file://{folder}/{side}.yaml")
    ]
    process = NodeProcess("stereo_node", NS, env, folder, args)
    with ros.running([process]):
        yield process


def test_compressed_images_and_camera_info_files_give_the_offline_disparity(
    ros: RosHarness, node: NodeProcess, tmp_path: Path
) -> None:
    frames = jpeg_frames()
    expected = offline(frames, tmp_path)
    left, right = (ros.publisher(CompressedImage, f"{NS}/{side}/image_raw/compressed") for side in ("left", "right"))
    disparity = ros.collector(DisparityImage, f"{NS}/disparity")
    wait_until(lambda: disparity.subscription.get_publisher_count() >= 1, "the node's disparity")
    for publisher in (left, right):
        wait_until(lambda p=publisher: p.get_subscription_count() >= 1, f"{publisher.topic_name} matched")
    for index, (stamp, left_jpeg, right_jpeg) in enumerate(frames):
        left.publish(left_jpeg)
        right.publish(right_jpeg)
        if index == DAMAGED:
            wait_until(lambda: "damaged JPEG" in node.output(), "the damaged JPEG reported")
            continue
        live = disparity_from_msg(disparity.wait_stamp(stamp))
        np.testing.assert_array_equal(live, expected[stamp], err_msg=f"frame {stamp}")
    assert sorted(disparity.stamps()) == sorted(expected)
    line = next(line for line in node.output().splitlines() if "damaged JPEG" in line)
    assert f"{NS}/left/image_raw/compressed" in line
    assert node.process.poll() is None and "Traceback" not in node.output()
    assert "calibration received (left = file://" in node.output()
    [refused] = ros.set_parameters(node.fqn, image_transport="raw")  # it chose the subscriptions
    assert not refused.successful and "read-only" in refused.reason
