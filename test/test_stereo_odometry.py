"""What stereo visual odometry (rtabmap's stereo_odometry, ORB-SLAM3, fovis) subscribes: left/image_rect,
right/image_rect, left/camera_info and right/camera_info, paired by exact stamp. From stereo_node over
real DDS on the bundled raw EuRoC bag (6 frames), and from `stereo-depth process`.
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from rclpy.serialization import deserialize_message
from ros_helpers import NodeProcess, RosHarness, reliable_qos, wait_until
from sensor_msgs.msg import CameraInfo, Image

from stereo_depth.bag.reader import StereoBagReader
from stereo_depth.bag.recording import open_reader
from stereo_depth.bag.types import rosbags_types
from stereo_depth.cli import main
from stereo_depth.core.params import make_params
from stereo_depth.frames import FrameStream
from stereo_depth.messages import array_to_image, image_to_array, stamp_to_ns
from stereo_depth.options import NodeOptions, Settings
from stereo_depth.ros.matching_node import camera_info_mismatch
from stereo_depth.sync import Synchronizer

BAG = Path(__file__).resolve().parents[1] / "bags" / "euroc_raw"
NS = "/stereo"  # the bag's namespace; this file's node is the only one under it while it runs
FRAMES = 6
VO_INPUTS = (
    ("left/image_rect", Image),
    ("right/image_rect", Image),
    ("left/camera_info", CameraInfo),
    ("right/camera_info", CameraInfo),
)
RECTIFIED = ("left/image_rect", "right/image_rect")


class ExactPairing:
    """A visual odometry node's input side: the four topics, paired by exact stamp (message_filters'
    TimeSynchronizer; here the package's own exact synchronizer)."""

    def __init__(self, ros: RosHarness) -> None:
        self.sync = Synchronizer(len(VO_INPUTS), queue_size=2 * FRAMES)
        self.sets: list[tuple[int, tuple[Any, ...]]] = []
        self._lock = threading.Lock()
        self.subscriptions = [
            ros.node.create_subscription(msg_type, f"{NS}/{name}", self._adder(index), reliable_qos(10))
            for index, (name, msg_type) in enumerate(VO_INPUTS)
        ]
        # the raw images too, ignored: the replay then waits for this side on every topic it publishes
        self.subscriptions += [
            ros.node.create_subscription(Image, f"{NS}/{side}/image_raw", lambda _msg: None, reliable_qos(10))
            for side in ("left", "right")
        ]

    def _adder(self, index: int) -> Callable[[Any], None]:
        return lambda msg: self._add(index, msg)

    def _add(self, index: int, msg: Any) -> None:
        with self._lock:
            self.sets.extend(self.sync.add(index, stamp_to_ns(msg.header.stamp), msg))


def replay_bag(env: dict[str, str]) -> None:
    # two subscribers on every topic: the node, and this file's VO side (which takes the camera_infos from
    # the bag, as a VO node takes them from the driver, and watches the raw images): none of its first
    # camera_infos may go out before it is matched
    command = [sys.executable, "-m", "stereo_depth.cli", "replay", str(BAG), "--wait-for-subscribers", "2"]
    command += ["--wait-timeout", "60"]
    command += [
        "--topics",
        *(f"{NS}/{side}/{kind}" for side in ("left", "right") for kind in ("image_raw", "camera_info")),
    ]
    replay = subprocess.run(command, env=env, capture_output=True, text=True, timeout=180, check=False)
    assert replay.returncode == 0, replay.stderr


def row_offset_px(left: np.ndarray, right: np.ndarray) -> float:
    """Median |dy| of ORB matches (cross-checked) between two images: 0 where rows correspond."""
    orb = cv2.ORB.create(2000)
    left_points, left_descriptors = orb.detectAndCompute(left, None)
    right_points, right_descriptors = orb.detectAndCompute(right, None)
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(left_descriptors, right_descriptors)
    assert len(matches) > 200, "too few ORB matches to judge the rows"
    dy = [left_points[m.queryIdx].pt[1] - right_points[m.trainIdx].pt[1] for m in matches]
    return float(np.median(np.abs(dy)))


def bag_messages(path: Path, types: dict[str, Any]) -> dict[str, dict[int, Any]]:
    """{name under NS: {stamp: rclpy message}} of a bag's topics named in `types`."""
    found: dict[str, dict[int, Any]] = {name: {} for name in types}
    reader = open_reader(path)
    try:
        for connection, _, raw in reader.messages(reader.connections):
            name = connection.topic.removeprefix(f"{NS}/")
            if name in types:
                msg = deserialize_message(bytes(raw), types[name])
                found[name][stamp_to_ns(msg.header.stamp)] = msg
    finally:
        reader.close()
    return found


@pytest.fixture(scope="module")
def live(
    ros: RosHarness, ros_env: dict[str, str], tmp_path_factory: pytest.TempPathFactory
) -> Iterator[list[tuple[int, tuple[Any, ...]]]]:
    """The bag replayed into stereo_node (room for every frame); the sets a VO subscriber paired."""
    node = NodeProcess("stereo_node", NS, ros_env, tmp_path_factory.mktemp("vo"), ["-p", "max_waiting_frames:=10"])
    with ros.running([node]):
        pairing = ExactPairing(ros)
        for subscription in pairing.subscriptions[:2]:
            wait_until(lambda s=subscription: s.get_publisher_count() >= 1, f"{subscription.topic_name} matched")
        replay_bag(ros_env)
        wait_until(lambda: len(pairing.sets) >= FRAMES, "a paired set for every frame", 120.0)
        yield pairing.sets
        for subscription in pairing.subscriptions:
            ros.node.destroy_subscription(subscription)


def test_a_vo_subscriber_pairs_both_rectified_images_and_camera_infos_for_every_frame(
    live: list[tuple[int, tuple[Any, ...]]],
) -> None:
    raw = bag_messages(BAG, {"left/image_raw": Image})["left/image_raw"]
    assert [stamp for stamp, _ in live] == sorted(raw)
    for _, (left, right, left_info, right_info) in live:
        assert {stamp_to_ns(m.header.stamp) for m in (left, right, left_info, right_info)} == {
            stamp_to_ns(left.header.stamp)
        }
        assert (left.header.frame_id, right.header.frame_id) == (left_info.header.frame_id, right_info.header.frame_id)
        assert (left.width, left.height) == (right.width, right.height) == (left_info.width, left_info.height)


def test_rectified_images_put_matching_features_on_one_row_and_raw_ones_do_not(
    live: list[tuple[int, tuple[Any, ...]]],
) -> None:
    raw = bag_messages(BAG, {"left/image_raw": Image, "right/image_raw": Image})
    for stamp, (left, right, _, _) in live:
        assert row_offset_px(image_to_array(left), image_to_array(right)) < 0.5
        # the same pair unrectified: the check can fail (EuRoC's cameras sit rows apart)
        assert (
            row_offset_px(image_to_array(raw["left/image_raw"][stamp]), image_to_array(raw["right/image_raw"][stamp]))
            > 2.0
        )


def test_process_writes_the_rectified_images_the_node_publishes(
    live: list[tuple[int, tuple[Any, ...]]], tmp_path: Path
) -> None:
    out = tmp_path / "offline"
    assert main(["process", str(BAG), str(out), "--outputs", *RECTIFIED]) == 0
    written = bag_messages(out, dict.fromkeys(RECTIFIED, Image))
    for stamp, messages in live:
        for name, msg in zip(RECTIFIED, messages, strict=False):
            assert written[name][stamp] == msg, f"{name} at {stamp}"


def test_a_16_bit_camera_keeps_its_brightness_when_one_pixel_saturates() -> None:
    """Both rectified images of a 16-bit camera are mono16 at the camera's own values: one saturated pixel
    changes that pixel's neighbourhood, not the brightness of the whole image (visual odometry tracks
    brightness between frames; the matcher's 8-bit images are scaled by each pair's peak)."""
    types = rosbags_types()
    with StereoBagReader(BAG) as reader:
        inputs = next(iter(reader.frames()))
        stream = FrameStream(types, make_params(), names=reader.topics.input_names)

        def wide(msg: Any, hot: bool) -> Any:
            pixels = image_to_array(msg).astype(np.uint16) * 16  # a 12-bit camera
            pixels[0, 0] = 65535 if hot else pixels[0, 0]
            return array_to_image(types, msg.header, pixels)

        outputs = [
            stream.match(
                dataclasses.replace(
                    inputs, left_image=wide(inputs.left_image, hot), right_image=wide(inputs.right_image, hot)
                ),
                RECTIFIED,
            ).images
            for hot in (False, True)
        ]
    for name in RECTIFIED:
        calm, hot = (image_to_array(images[name]) for images in outputs)
        assert outputs[0][name].encoding == "mono16" and calm.dtype == np.uint16
        away = np.ones(calm.shape, bool)
        away[:8, :8] = False  # the saturated pixel's neighbourhood, wherever rectification moved it
        assert np.array_equal(calm[away], hot[away]), name


@pytest.mark.parametrize(
    ("stereo", "node"),
    [
        ({"downsample": 2, "downsample_output": "processed"}, {}),
        ({}, {"left_camera_info_url": "file:///calibration/left.yaml"}),
    ],
    ids=("downsample_output_processed", "camera_info_url"),
)
def test_a_node_says_when_its_camera_infos_cannot_describe_the_rectified_images(
    stereo: dict[str, Any], node: dict[str, Any]
) -> None:
    """What a VO node pairs the rectified images with is the camera_info topics: where those describe other
    images (or none is published), the node says so (once) instead of feeding odometry a wrong model."""
    assert camera_info_mismatch(Settings(make_params(), NodeOptions())) is None
    assert camera_info_mismatch(Settings(make_params("default", {"downsample": 2}), NodeOptions())) is None
    mismatch = camera_info_mismatch(Settings(make_params("default", stereo), NodeOptions(**node)))
    assert mismatch is not None and "stereo odometry" in mismatch
