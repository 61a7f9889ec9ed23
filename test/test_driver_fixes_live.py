"""stereo_node over real DDS on a driver whose right camera_info has no baseline (RealSense infra1/infra2
and others publish P[0,3] = 0): the `baseline` parameter restores the calibrated depth and is logged once
at start; without it the disparity still goes out, and depth and points2 are skipped with one warning."""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from ros_helpers import NodeProcess, RosHarness, wait_until
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from stereo_msgs.msg import DisparityImage

from stereo_depth.core.camera import StereoCamera
from stereo_depth.core.params import make_params
from stereo_depth.core.pipeline import StereoPipeline
from stereo_depth.formats.scenes import load_scene
from stereo_depth.messages import array_to_image, camera_info_to_msg, disparity_from_msg, image_to_array, make_header
from stereo_depth.ros.types import RCLPY_TYPES

from conftest import SCENES

FRAME = "left_optical_frame"
NS = "/fix"
SCENE = load_scene(SCENES / "artl")
LEFT_INFO, RIGHT_INFO = SCENE.camera_infos(FRAME)
CAMERA = StereoCamera(LEFT_INFO, RIGHT_INFO)
_stamps = itertools.count(1_720_000_000 * 10**9, 100_000_000)
NO_BASELINE = "gives baseline 0 m: disparity is published, but depth and points2 are not"


def right_without_baseline() -> Any:
    p = RIGHT_INFO.p.copy()
    p[0, 3] = 0.0
    return type(RIGHT_INFO).from_values(
        RIGHT_INFO.width, RIGHT_INFO.height, RIGHT_INFO.k, RIGHT_INFO.d, RIGHT_INFO.r, p, "plumb_bob", FRAME
    )


@pytest.fixture(scope="module")
def node(ros: RosHarness, ros_env: dict[str, str], tmp_path_factory: pytest.TempPathFactory) -> Iterator[NodeProcess]:
    process = NodeProcess(
        "stereo_node", NS, ros_env, tmp_path_factory.mktemp("fix_logs"), ["-p", f"baseline:={CAMERA.baseline!r}"]
    )
    with ros.running([process]):
        yield process


@pytest.fixture(scope="module")
def io(ros: RosHarness, node: NodeProcess) -> dict[str, Any]:
    del node
    outputs = {
        "disparity": ros.collector(DisparityImage, f"{NS}/disparity"),
        "depth": ros.collector(Image, f"{NS}/depth"),
        "points2": ros.collector(PointCloud2, f"{NS}/points2"),
    }
    for collector in outputs.values():
        wait_until(lambda c=collector: c.subscription.get_publisher_count() >= 1, "outputs matched")
    kinds = {"left/image_raw": Image, "left/camera_info": CameraInfo, "right/image_raw": Image}
    publishers = {name: ros.publisher(kind, f"{NS}/{name}") for name, kind in kinds.items()}
    publishers["right/camera_info"] = ros.publisher(CameraInfo, f"{NS}/right/camera_info")
    for publisher in publishers.values():
        wait_until(lambda p=publisher: p.get_subscription_count() >= 1, f"{publisher.topic_name} matched")
    return {"publishers": publishers, **outputs}


def publish(io: dict[str, Any], stamp: int) -> None:
    header = make_header(RCLPY_TYPES, stamp, FRAME)
    messages = {
        "left/image_raw": array_to_image(RCLPY_TYPES, header, SCENE.left),
        "left/camera_info": camera_info_to_msg(RCLPY_TYPES, header, LEFT_INFO),
        "right/image_raw": array_to_image(RCLPY_TYPES, header, SCENE.right),
        "right/camera_info": camera_info_to_msg(RCLPY_TYPES, header, right_without_baseline()),
    }
    for name, message in messages.items():
        io["publishers"][name].publish(message)


def calibrated() -> Any:
    """What the pipeline gives with the true calibration."""
    return StereoPipeline(make_params()).process(SCENE.left, SCENE.right, CAMERA, want_points=False)


def test_baseline_parameter_gives_the_calibrated_depth_and_is_logged_once(
    io: dict[str, Any], node: NodeProcess
) -> None:
    stamp = next(_stamps)
    publish(io, stamp)
    depth = image_to_array(io["depth"].wait_stamp(stamp))
    disparity = io["disparity"].wait_stamp(stamp)
    io["points2"].wait_stamp(stamp)
    expected = calibrated()
    np.testing.assert_allclose(depth, expected.depth, rtol=1e-6)  # P[0,3] rebuilt from the baseline: an ulp
    assert disparity.t == np.float32(CAMERA.baseline)
    log = node.output()
    assert log.count("inputs corrected: baseline") == 1, log
    assert NO_BASELINE not in log


def test_without_baseline_disparity_goes_out_and_one_warning_says_why(
    ros: RosHarness, io: dict[str, Any], node: NodeProcess
) -> None:
    assert ros.set_parameters(f"{NS}/stereo_node", baseline=0.0)[0].successful
    stamps = [next(_stamps) for _ in range(3)]
    for stamp in stamps:
        publish(io, stamp)
        received = io["disparity"].wait_stamp(stamp)  # one set at a time: each pairs with its own camera_info
    wait_until(lambda: NO_BASELINE in node.output(), "the warning")
    assert not set(stamps) & {*io["depth"].stamps(), *io["points2"].stamps()}
    expected = calibrated().disparity - np.float32(CAMERA.disparity_offset)
    np.testing.assert_array_equal(disparity_from_msg(received), expected)
    log = node.output()
    assert log.count(NO_BASELINE) == 1, log
    assert "set the baseline parameter" in log
