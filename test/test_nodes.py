"""The nodes over real DDS, each in its own process, fed real scenes from this test process.

One stereo_node (/live) and one split chain (/split: rectify_node x2 -> disparity_node ->
point_cloud_node) run for the whole module; every input set gets a fresh, increasing stamp.
"""

from __future__ import annotations

import dataclasses
import itertools
import signal
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.qos import ReliabilityPolicy
from ros_helpers import TIMEOUT_S, NodeProcess, RosHarness, stop_all, wait_until
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from stereo_msgs.msg import DisparityImage

from stereo_depth.core.camera import CameraInfo as Calibration
from stereo_depth.core.params import make_params
from stereo_depth.core.pipeline import StereoPipeline, StereoResult
from stereo_depth.formats.euroc import stereo_camera_infos
from stereo_depth.formats.scenes import load_scene
from stereo_depth.frames import valid_region
from stereo_depth.messages import (
    array_to_image,
    camera_info_to_msg,
    cloud_to_arrays,
    disparity_from_msg,
    disparity_to_msg,
    image_to_array,
    image_to_pipeline,
    make_header,
    pack_rgb,
)
from stereo_depth.ros.transport import PROFILE_VARIABLES
from stereo_depth.ros.types import RCLPY_TYPES

from conftest import EUROC, SCENES, read_image

FRAME = "camera_left_optical_frame"
_stamps = itertools.count(1_700_000_000 * 10**9, 500_000_000)


class StereoInput:
    """Publishers for the four inputs of a stereo pair under one namespace."""

    def __init__(self, ros: RosHarness, namespace: str) -> None:
        self.publishers = [
            ros.publisher(Image, f"{namespace}/left/image_raw"),
            ros.publisher(CameraInfo, f"{namespace}/left/camera_info"),
            ros.publisher(Image, f"{namespace}/right/image_raw"),
            ros.publisher(CameraInfo, f"{namespace}/right/camera_info"),
        ]

    def wait_matched(self, images: int = 1, infos: int = 1) -> None:
        for publisher, count in zip(self.publishers, (images, infos, images, infos), strict=True):
            wait_until(lambda p=publisher, n=count: p.get_subscription_count() >= n, f"{publisher.topic_name} matched")

    def publish(
        self,
        pair: Pair,
        stamp: int,
        right_stamp: int | None = None,
        left_encoding: str | None = None,
        order: tuple[int, ...] = (0, 1, 2, 3),
    ) -> None:
        """The inputs named by `order` (0 left image, 1 left info, 2 right image, 3 right info), in that order."""
        right_stamp = stamp if right_stamp is None else right_stamp
        left_header = make_header(RCLPY_TYPES, stamp, FRAME)
        right_header = make_header(RCLPY_TYPES, right_stamp, FRAME)
        left = array_to_image(RCLPY_TYPES, left_header, pair.left)
        if left_encoding is not None:
            left.encoding = left_encoding
        messages = (
            left,
            camera_info_to_msg(RCLPY_TYPES, left_header, pair.left_info),
            array_to_image(RCLPY_TYPES, right_header, pair.right),
            camera_info_to_msg(RCLPY_TYPES, right_header, pair.right_info),
        )
        for index in order:
            self.publishers[index].publish(messages[index])


def send_with_parameters(
    ros: RosHarness, node_fqn: str, inputs: StereoInput, outputs: dict[str, Any], pair: Pair, stamp: int, **options: Any
) -> dict[str, Any]:
    """Set `options` on the node, send `pair` once at `stamp`, return each of `outputs`' message of that
    frame (collectors by name); the options are restored afterwards."""
    previous = ros.get_parameters(node_fqn, *options)
    results = ros.set_parameters(node_fqn, **options)
    assert all(r.successful for r in results), [r.reason for r in results]
    try:
        inputs.publish(pair, stamp)
        return {name: collector.wait_stamp(stamp) for name, collector in outputs.items()}
    finally:  # undone last first: a rule across options (cloud_voxel_size needs organized_cloud false) holds
        ros.set_parameters(node_fqn, **dict(reversed(previous.items())))


class Pair:
    def __init__(self, left: np.ndarray, right: np.ndarray, infos: tuple[Calibration, Calibration]) -> None:
        self.left, self.right = left, right
        self.left_info, self.right_info = infos

    def offline(self, **overrides: Any) -> StereoResult:
        """What StereoPipeline gives without ROS for the pixels the node decodes."""
        pipeline = StereoPipeline(make_params("default", overrides))
        camera = pipeline.camera_for(self.left_info, self.right_info)
        header = make_header(RCLPY_TYPES, 0, FRAME)
        decode = lambda a: image_to_pipeline(array_to_image(RCLPY_TYPES, header, a))  # noqa: E731
        return pipeline.process(decode(self.left), decode(self.right), camera)


@pytest.fixture(scope="module")
def artl() -> Pair:
    """Middlebury scene whose two cameras have different cx: the offset must be subtracted once."""
    scene = load_scene(SCENES / "artl")
    return Pair(scene.left, scene.right, scene.camera_infos(FRAME))


@pytest.fixture(scope="module")
def euroc() -> Pair:
    return euroc_pair()


def euroc_pair() -> Pair:
    """Raw, distorted EuRoC pair: only the nodes' rectification makes it matchable."""
    name = sorted((EUROC / "left").glob("*.png"))[0].name
    left = read_image(EUROC / "left" / name, cv2.IMREAD_GRAYSCALE)
    right = read_image(EUROC / "right" / name, cv2.IMREAD_GRAYSCALE)
    return Pair(left, right, stereo_camera_infos(EUROC / "cam0_sensor.yaml", EUROC / "cam1_sensor.yaml", FRAME))


@pytest.fixture(scope="module")
def nodes(
    ros: RosHarness, ros_env: dict[str, str], tmp_path_factory: pytest.TempPathFactory
) -> Iterator[dict[str, NodeProcess]]:
    logs = tmp_path_factory.mktemp("node_logs")
    processes = {
        # a misspelt parameter: warned about once at start-up, otherwise ignored (the tests below see defaults)
        "live": NodeProcess("stereo_node", "/live", ros_env, logs, ["-p", "dispartiy_range:=128"]),
        "events": NodeProcess("stereo_node", "/events", ros_env, logs, ["-p", "executor:=events"]),
        "rectify_left": NodeProcess("rectify_node", "/split/left", ros_env, logs, ["-r", "image:=image_raw"]),
        "rectify_right": NodeProcess("rectify_node", "/split/right", ros_env, logs, ["-r", "image:=image_raw"]),
        "disparity": NodeProcess("disparity_node", "/split", ros_env, logs),
        "points": NodeProcess(
            "point_cloud_node", "/split", ros_env, logs, ["-r", "left/image_rect_color:=left/image_rect"]
        ),
    }
    with ros.running(processes.values()):
        yield processes


@pytest.fixture(scope="module")
def live(ros: RosHarness, nodes: dict[str, NodeProcess]) -> dict[str, Any]:
    """Inputs and collected outputs of /live/stereo_node, matched before anything is published."""
    outputs = {
        "disparity": ros.collector(DisparityImage, "/live/disparity"),
        "depth": ros.collector(Image, "/live/depth"),
        "points2": ros.collector(PointCloud2, "/live/points2"),
        "diagnostics": ros.collector(DiagnosticArray, "/live/diagnostics"),
    }
    for collector in outputs.values():
        wait_until(lambda c=collector: c.subscription.get_publisher_count() >= 1, "outputs matched")
    inputs = StereoInput(ros, "/live")
    inputs.wait_matched()
    return {"inputs": inputs, **outputs}


def test_stereo_node_output_equals_offline_pipeline(live: dict[str, Any], artl: Pair) -> None:
    stamp = next(_stamps)
    live["inputs"].publish(artl, stamp)
    disparity_msg = live["disparity"].wait_stamp(stamp)
    depth_msg = live["depth"].wait_stamp(stamp)
    cloud_msg = live["points2"].wait_stamp(stamp)

    expected = artl.offline()
    camera = expected.camera
    assert camera is not None
    height, width = expected.disparity.shape
    window = valid_region(expected.disparity)
    reference = disparity_to_msg(RCLPY_TYPES, disparity_msg.header, expected.disparity, camera, 0, 64, window)
    assert camera.disparity_offset == -50.0  # cx_l 148, cx_r 198
    assert disparity_msg.header.frame_id == FRAME
    assert disparity_msg.image.encoding == "32FC1"
    assert bytes(disparity_msg.image.data) == bytes(reference.image.data)  # bit for bit
    assert (disparity_msg.f, disparity_msg.t) == (camera.fx, pytest.approx(0.160))
    assert disparity_msg.min_disparity == 50.0  # 0 - (cx_l - cx_r), the offset subtracted once
    assert disparity_msg.max_disparity == 50.0 + 63.0
    assert disparity_msg.delta_d == 1.0 / 16.0
    roi = disparity_msg.valid_window
    assert (roi.x_offset, roi.y_offset, roi.width, roi.height) == window
    assert 0 < roi.x_offset < width and 0 < roi.width < width  # SGBM: nothing left of its search range

    image = image_to_array(disparity_msg.image)
    invalid = ~np.isfinite(expected.disparity)
    assert invalid.any() and np.all(image[invalid] == disparity_msg.min_disparity - 1.0)
    assert np.all(image[~invalid] >= disparity_msg.min_disparity)

    assert depth_msg.encoding == "32FC1" and depth_msg.header.stamp == disparity_msg.header.stamp
    np.testing.assert_array_equal(image_to_array(depth_msg), expected.depth)

    assert (cloud_msg.height, cloud_msg.width) == (height, width)
    assert [(f.name, f.offset, f.datatype, f.count) for f in cloud_msg.fields] == [
        ("x", 0, 7, 1),
        ("y", 4, 7, 1),
        ("z", 8, 7, 1),
        ("rgb", 16, 7, 1),
    ]
    assert cloud_msg.point_step == 32 and cloud_msg.row_step == 32 * width and not cloud_msg.is_dense
    assert cloud_msg.header.frame_id == FRAME
    xyz, rgb = cloud_to_arrays(cloud_msg)
    np.testing.assert_array_equal(xyz[:, :, 2], expected.depth)
    valid = np.isfinite(xyz[:, :, 2])
    assert valid.mean() > 0.5
    v, u = np.nonzero(valid)
    x, y, z = (xyz[valid][:, i].astype(np.float64) for i in range(3))
    np.testing.assert_allclose(camera.fx * x / z + camera.cx_left, u, atol=1e-3)
    np.testing.assert_allclose(camera.fy * y / z + camera.cy, v, atol=1e-3)
    np.testing.assert_array_equal(rgb, pack_rgb(artl.left))  # identity rectification: scene colours


def wait_until_delivered(inputs: StereoInput, output: Any, pair: Pair, every_s: float = 3.0) -> None:
    """Probe sets until one comes out of `output` (a node, or the end of a node chain). Each node
    publishes, and builds outputs lazily, for the subscribers it has discovered itself, and this process's
    view of the graph can be ahead of a node's: a frame sent when this process sees every edge can still
    be dropped (rectify_node published left/image_rect before it had matched point_cloud_node; a fresh
    stereo_node built no depth for a collector it had not matched yet). One probe through proves every
    edge matched; discovery is not undone, so the frames after it arrive."""
    probes: list[int] = []
    deadline = time.monotonic() + TIMEOUT_S * 3
    while time.monotonic() < deadline:
        probes.append(next(_stamps))
        inputs.publish(pair, probes[-1])
        try:
            wait_until(lambda: any(output.find(stamp) for stamp in probes), "a probe through the chain", every_s)
        except TimeoutError:
            continue
        return
    msg = f"no probe came out of {output.subscription.topic_name}: {len(probes)} sent"
    raise TimeoutError(msg)


def test_split_chain_gives_the_same_cloud_as_stereo_node(ros: RosHarness, live: dict[str, Any], euroc: Pair) -> None:
    split_disparity = ros.collector(DisparityImage, "/split/disparity")
    split_points = ros.collector(PointCloud2, "/split/points2")
    for collector in (split_disparity, split_points):
        wait_until(lambda c=collector: c.subscription.get_publisher_count() >= 1, "split outputs matched")
    split_inputs = StereoInput(ros, "/split")
    split_inputs.wait_matched(infos=3)  # camera_info goes to rectify_node, disparity_node and point_cloud_node
    wait_until_delivered(split_inputs, split_points, euroc)

    stamp = next(_stamps)
    split_inputs.publish(euroc, stamp)
    live["inputs"].publish(euroc, stamp)
    live_cloud, split_cloud = live["points2"].wait_stamp(stamp), split_points.wait_stamp(stamp)
    live_disparity, chain_disparity = live["disparity"].wait_stamp(stamp), split_disparity.wait_stamp(stamp)

    camera = euroc.offline().camera
    assert camera is not None and camera.needs_rectification("left")
    assert bytes(chain_disparity.image.data) == bytes(live_disparity.image.data)
    assert chain_disparity.valid_window == live_disparity.valid_window
    assert list(split_cloud.fields) == list(live_cloud.fields)
    assert (split_cloud.height, split_cloud.width) == (live_cloud.height, live_cloud.width)
    assert bytes(split_cloud.data) == bytes(live_cloud.data)
    assert np.isfinite(cloud_to_arrays(live_cloud)[0][:, :, 2]).mean() > 0.3


def test_the_events_executor_gives_the_same_outputs_and_takes_parameters(
    ros: RosHarness, live: dict[str, Any], nodes: dict[str, NodeProcess], artl: Pair
) -> None:
    """executor:=events (rclpy's C++ EventsExecutor, which calls subscriptions with the message alone): the
    outputs of /live (standard executor) for the same pair, bit for bit; parameters set at run time take
    effect as there; `executor` itself is read-only once running."""
    node = nodes["events"]
    outputs = {"disparity": ros.collector(DisparityImage, "/events/disparity")}
    outputs["points2"] = ros.collector(PointCloud2, "/events/points2")
    for collector in outputs.values():
        wait_until(lambda c=collector: c.subscription.get_publisher_count() >= 1, "outputs matched")
    inputs = StereoInput(ros, "/events")
    inputs.wait_matched()
    wait_until_delivered(inputs, outputs["points2"], artl)

    stamp = next(_stamps)
    live["inputs"].publish(artl, stamp)
    inputs.publish(artl, stamp)
    disparity, standard = outputs["disparity"].wait_stamp(stamp), live["disparity"].wait_stamp(stamp)
    assert bytes(disparity.image.data) == bytes(standard.image.data)
    assert bytes(outputs["points2"].wait_stamp(stamp).data) == bytes(live["points2"].wait_stamp(stamp).data)

    wider = send_with_parameters(ros, node.fqn, inputs, outputs, artl, next(_stamps), disparity_range=128)
    assert wider["disparity"].max_disparity == disparity.max_disparity + 64
    [refused] = ros.set_parameters(node.fqn, executor="standard")
    assert not refused.successful and "read-only" in refused.reason
    assert "executor: rclpy's EventsExecutor" in node.output()  # it ran the one asked for


def test_approximate_sync_pairs_only_within_tolerance(ros: RosHarness, live: dict[str, Any], artl: Pair) -> None:
    fqn = "/live/stereo_node"
    results = ros.set_parameters(fqn, approximate_sync=True, approximate_sync_tolerance_seconds=0.01)
    assert all(r.successful for r in results)
    try:
        sent: dict[int, bool] = {}
        for offset_ms in (0, 4, 9, 15, 40, 300, 2):
            stamp = next(_stamps)
            live["inputs"].publish(artl, stamp, right_stamp=stamp + offset_ms * 1_000_000)
            sent[stamp] = offset_ms <= 10
            if sent[stamp]:
                live["disparity"].wait_stamp(stamp)  # one set at a time: none is replaced while busy
        received = set(live["disparity"].stamps())
        assert {s for s in sent if s in received} == {s for s, paired in sent.items() if paired}
    finally:
        ros.set_parameters(fqn, approximate_sync=False)


def test_runtime_parameter_change_changes_output_and_invalid_is_refused(
    ros: RosHarness, live: dict[str, Any], artl: Pair
) -> None:
    fqn = "/live/stereo_node"
    [ok] = ros.set_parameters(fqn, disparity_range=32)
    assert ok.successful
    try:
        refused = ros.set_parameters(fqn, P1=1000.0, disparity_range=40, matcher="magic", correlation_window_size=4)
        assert [r.successful for r in refused] == [False] * 4
        assert "P2" in refused[0].reason and "matcher 'magic' is unknown" in refused[2].reason
        assert ros.get_parameters(fqn, "P1", "disparity_range", "matcher") == {
            "P1": 200.0,
            "disparity_range": 32,
            "matcher": "sgbm",
        }
        stamp = next(_stamps)
        live["inputs"].publish(artl, stamp)
        msg = live["disparity"].wait_stamp(stamp)
        assert msg.max_disparity == 50.0 + 31.0
        expected = artl.offline(disparity_range=32)
        assert expected.camera is not None
        reference = disparity_to_msg(RCLPY_TYPES, msg.header, expected.disparity, expected.camera, 0, 32, (0, 0, 0, 0))
        assert bytes(msg.image.data) == bytes(reference.image.data)

        [alias] = ros.set_parameters(fqn, stereo_algorithm=0)  # stereo_image_proc's name for matcher
        assert alias.successful and ros.get_parameters(fqn, "matcher") == {"matcher": "bm"}
    finally:
        ros.set_parameters(fqn, disparity_range=64, matcher="sgbm")


def test_burst_into_two_matching_threads_keeps_input_order_and_counts_every_set(
    ros: RosHarness, live: dict[str, Any], euroc: Pair
) -> None:
    """With matching_threads:=2, sets sent faster than the node may match them come out in input order,
    the newest among them, and each set is either published or counted as dropped, whether or not this
    machine keeps up. (The test's own subscriber may miss some of a burst: the node's counters are the
    reference.)"""
    fqn = "/live/stereo_node"
    diagnostics = live["diagnostics"]

    def counter(key: str) -> int:
        return int(next(kv.value for kv in diagnostics.messages[-1].status[0].values if kv.key == key))

    def fresh_diagnostics() -> None:
        seen = len(diagnostics.messages)
        wait_until(lambda: len(diagnostics.messages) > seen, "a diagnostics report")

    assert all(r.successful for r in ros.set_parameters(fqn, matching_threads=2, sgbm_mode=0))
    keys = ("frames processed", "dropped clouds (depth, points2)", "dropped frames")
    try:
        warm = next(_stamps)
        live["inputs"].publish(euroc, warm)
        live["points2"].wait_stamp(warm)
        fresh_diagnostics()
        before = [counter(k) for k in keys]
        sent = [next(_stamps) for _ in range(12)]
        for stamp in sent:
            live["inputs"].publish(euroc, stamp)
            time.sleep(0.02)
        live["disparity"].wait_stamp(sent[-1])
        got = [s for s in live["disparity"].stamps() if s in sent]
        assert got == sorted(set(got)) and got[-1] == sent[-1]

        # Each set is published (then finished, or its cloud dropped) or dropped; a set overtaken by the
        # newest one is counted when its own matching ends, maybe a report later.
        def accounted() -> list[int]:
            return [counter(k) - b for k, b in zip(keys, before, strict=True)]

        wait_until(lambda: sum(accounted()) == len(sent), "every set accounted for")
    finally:
        ros.set_parameters(fqn, matching_threads=1, sgbm_mode=2)


def test_a_latency_budget_no_frame_can_meet_drops_the_frames_unprocessed_and_counts_them(
    ros: RosHarness, live: dict[str, Any], euroc: Pair
) -> None:
    """max_latency_ms below the time one frame takes: sets are dropped before matching and counted as
    too late; one a second still runs, so the node notices when the machine becomes fast enough."""
    fqn = "/live/stereo_node"
    keys = (
        "frames processed",
        "dropped frames",
        "dropped clouds (depth, points2)",
        "dropped as too late for max_latency_ms (frames and clouds)",
    )
    warm = next(_stamps)
    live["inputs"].publish(euroc, warm)  # the time per frame is measured
    live["points2"].wait_stamp(warm)
    assert all(r.successful for r in ros.set_parameters(fqn, max_latency_ms=0.01))
    try:
        before = node_counters(live["diagnostics"], *keys)
        sent = [next(_stamps) for _ in range(6)]
        for stamp in sent:
            live["inputs"].publish(euroc, stamp)
            time.sleep(0.05)

        def accounted() -> list[int] | None:
            counts = [n - b for n, b in zip(node_counters(live["diagnostics"], *keys), before, strict=True)]
            return counts if sum(counts[:3]) >= len(sent) else None

        processed, dropped, _, too_late = wait_until(accounted, "every set processed or dropped")
    finally:
        ros.set_parameters(fqn, max_latency_ms=0.0)
    assert dropped >= 1 and too_late >= 1  # sets dropped before matching, as too late
    assert processed < len(sent)  # no more than the probes got through


def node_counters(diagnostics: Any, *keys: str) -> list[int]:
    """The node's counters in a report that came after this call (0 for a counter not reported yet)."""
    seen = len(diagnostics.messages)
    wait_until(lambda: len(diagnostics.messages) > seen, "a diagnostics report")
    values = {kv.key: kv.value for kv in diagnostics.messages[-1].status[0].values}
    return [int(values.get(key, 0)) for key in keys]


STOOD_IN = "/live/left/camera_info missing, last one used"
PUBLISH_ORDERS = {
    "camera_info first": (1, 3, 0, 2),
    "each camera_info after its image": (0, 1, 2, 3),
    "images first": (0, 2, 1, 3),
    "right camera first, info last": (2, 0, 3, 1),
}


def test_every_publish_order_and_a_lagging_right_camera_pair_every_set(live: dict[str, Any], artl: Pair) -> None:
    """A driver may publish the four topics in any order, and one camera may lag the other by frames:
    every set is still paired, no input message is left unmatched. A camera_info that never comes (DDS
    lost it) costs no frame: the last one stands in, counted per topic."""
    keys = ("unmatched input messages", "dropped frames", "frames processed")
    before = node_counters(live["diagnostics"], *keys, STOOD_IN)
    sent = []
    for order in PUBLISH_ORDERS.values():
        for _ in range(3):
            sent.append(next(_stamps))
            live["inputs"].publish(artl, sent[-1], order=order)
            live["disparity"].wait_stamp(sent[-1])
    lag = 2  # the right camera's messages of frame k come after the left camera's of frame k + 2
    skewed = [next(_stamps) for _ in range(6)]
    for k in range(len(skewed) + lag):
        if k < len(skewed):
            live["inputs"].publish(artl, skewed[k], order=(1, 0))
        if k >= lag:
            live["inputs"].publish(artl, skewed[k - lag], order=(3, 2))
            live["disparity"].wait_stamp(skewed[k - lag])
    sent += skewed
    lost, after = next(_stamps), next(_stamps)
    live["inputs"].publish(artl, lost, order=(3, 0, 2))  # its left camera_info lost on the way
    live["inputs"].publish(artl, after, order=(1,))  # the left camera_info topic moves on: `lost` goes out
    live["disparity"].wait_stamp(lost)
    live["inputs"].publish(artl, after, order=(3, 0, 2))
    sent += [lost, after]

    def accounted() -> bool:
        unmatched, dropped, processed, stood_in = node_counters(live["diagnostics"], *keys, STOOD_IN)
        assert (unmatched, dropped) == tuple(before[:2])
        return processed - before[2] == len(sent) and stood_in > before[3]

    wait_until(accounted, "every set processed, one with the last left camera_info")
    assert set(sent) <= set(live["disparity"].stamps())


def test_bad_input_is_skipped_reported_and_survived(live: dict[str, Any], artl: Pair) -> None:
    before = next(_stamps)  # a good frame first: the report then has stage times, whichever test ran before
    live["inputs"].publish(artl, before)
    live["disparity"].wait_stamp(before)
    bad = next(_stamps)
    live["inputs"].publish(artl, bad, left_encoding="yuv422")

    def reported() -> dict[str, str] | None:
        for array in reversed(live["diagnostics"].messages):
            values = {kv.key: kv.value for kv in array.status[0].values}
            if "yuv422" in values.get("last error", ""):
                return values
        return None

    values = wait_until(reported, "the bad frame in diagnostics")
    assert "/live/left/image_raw" in values["last error"]  # names the topic
    for key in (
        "/live/left/image_raw rate (Hz)",
        "output rate (Hz)",
        "match time (ms)",
        "rectify time (ms)",
        "latency from stamp (s)",
        "disparity age at publish (ms)",
        "points2 age at publish (ms)",
        "dropped frames",
        "frames processed",
    ):
        assert key in values, key
    assert float(values["disparity age at publish (ms)"]) > 0 and float(values["points2 age at publish (ms)"]) > 0
    # from the DDS sample info: the harness's write to the node's reader, one machine, one clock
    in_dds = [float(v) for v in values["/live/left/image_raw time in DDS (ms, median / max)"].split(" / ")]
    assert 0.0 <= in_dds[0] <= in_dds[1] < 60_000.0, in_dds
    good = next(_stamps)
    live["inputs"].publish(artl, good)
    live["disparity"].wait_stamp(good)
    assert bad not in live["disparity"].stamps()


def test_input_reliability_follows_the_publishers(ros: RosHarness, live: dict[str, Any]) -> None:
    topic = "/live/right/image_raw"

    def node_reliability() -> ReliabilityPolicy | None:
        infos = [i for i in ros.node.get_subscriptions_info_by_topic(topic) if i.node_name == "stereo_node"]
        return infos[0].qos_profile.reliability if infos else None

    assert node_reliability() == ReliabilityPolicy.RELIABLE
    best_effort = ros.publisher(Image, topic, ReliabilityPolicy.BEST_EFFORT)
    wait_until(lambda: node_reliability() == ReliabilityPolicy.BEST_EFFORT, "a best-effort subscription")
    wait_until(lambda: best_effort.get_subscription_count() >= 1, "the best-effort publisher matched")
    ros.node.destroy_publisher(best_effort)
    wait_until(lambda: node_reliability() == ReliabilityPolicy.RELIABLE, "back to reliable")
    live["inputs"].wait_matched()


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_signal_ends_every_node_cleanly(
    ros: RosHarness, ros_env: dict[str, str], tmp_path: Path, sig: signal.Signals
) -> None:
    namespace = f"/{sig.name.lower()}"
    processes = [
        NodeProcess(module, namespace, ros_env, tmp_path)
        for module in ("stereo_node", "disparity_node", "point_cloud_node", "rectify_node")
    ]
    processes.append(NodeProcess("stereo_node", f"{namespace}_events", ros_env, tmp_path, ["-p", "executor:=events"]))
    try:
        ros.wait_for_nodes(processes)
    finally:
        stop_all(processes, sig)  # asserts exit code 0 and no traceback for each


def _catches(pid: int, sig: signal.Signals) -> bool:
    """Whether process `pid` has a handler for `sig` (its SigCgt mask in /proc)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except FileNotFoundError:  # it has ended: the caller sees that next
        return False
    caught = int(next(line.split()[1] for line in status.splitlines() if line.startswith("SigCgt:")), 16)
    return bool(caught >> (sig - 1) & 1)


@pytest.mark.parametrize("as_module", [False, True], ids=["console script", "python -m"])
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_signal_at_any_moment_of_start_up_ends_the_node_quietly(
    start_node: Callable[..., NodeProcess], sig: signal.Signals, as_module: bool
) -> None:
    """Ctrl-C (or a launch file's SIGTERM) right after the console script (or `python -m`) put its handlers
    in, while the node's modules are still being imported, ends it with exit code 0 before it prints
    anything; so do signals later in its start-up, without a traceback or an exception printed as ignored
    (an exception raised inside an import or a callback, where it is swallowed and the node runs on)."""
    for delay in (0.0, 0.3, 0.8):
        namespace = f"/early_{sig.name.lower()}_{delay * 10:.0f}_{'m' if as_module else 's'}"
        process = start_node("stereo_node", namespace, as_module=as_module)
        child = process.process
        wait_until(lambda c=child: c.poll() is not None or _catches(c.pid, signal.SIGTERM), "handlers", 60.0, 0.001)
        if delay == 0.0 and child.poll() is None:  # the handlers came before the imports: no rclpy yet
            assert "_rclpy_pybind11" not in Path(f"/proc/{child.pid}/maps").read_text()
        time.sleep(delay)
        code, output = process.stop(sig)
        assert code == 0, output
        assert "Traceback" not in output and "Exception ignored" not in output, output
        if delay == 0.0:
            assert output == "", output  # ended during its imports


def test_a_census_node_loads_its_core_before_it_subscribes_its_inputs(ros_env: dict[str, str], tmp_path: Path) -> None:
    """profile:=quality: numba's machine code is loaded at start (compiled first on a fresh install:
    ~30 s), before any input is subscribed, so no frame waits for it; the log says where the time went."""
    process = NodeProcess("stereo_node", "/census_start", ros_env, tmp_path, ["-p", "profile:=quality"])
    try:
        wait_until(lambda: "ready: inputs" in process.output() or process.process.poll() is not None, "ready", 300.0)
    finally:
        stop_all([process])
    lines = process.output().splitlines()
    loaded = [i for i, line in enumerate(lines) if "census_sgm core ready in" in line]
    ready = [i for i, line in enumerate(lines) if "ready: inputs" in line]
    assert len(loaded) == 1 and len(ready) == 1 and loaded[0] < ready[0], process.output()


def test_nodes_that_do_not_come_up_are_stopped_not_left_to_answer_a_later_run(
    ros: RosHarness, ros_env: dict[str, str], tmp_path: Path
) -> None:
    """A fixture whose nodes time out at start-up stops them; here one runs under another node name, so
    the wait for it times out though it is alive."""
    process = NodeProcess("rectify_node", "/orphan", ros_env, tmp_path, ["-r", "__node:=renamed"])
    with pytest.raises(TimeoutError), ros.running([process], timeout=3.0):
        pass
    assert process.process.poll() is not None


def test_a_misspelt_parameter_is_named_once_with_the_closest_known_one(nodes: dict[str, NodeProcess]) -> None:
    live = nodes["live"]
    wait_until(lambda: "unknown parameters" in live.output(), "the start-up warning")
    lines = [line for line in live.output().splitlines() if "unknown parameters" in line]
    assert len(lines) == 1 and "WARN" in lines[0]
    assert "'dispartiy_range' (did you mean 'disparity_range'?)" in lines[0]
    assert "unknown parameters" not in nodes["disparity"].output()


def test_every_node_started_without_a_profile_maps_the_large_shared_memory_segment(
    nodes: dict[str, NodeProcess], ros_env: dict[str, str]
) -> None:
    """run_node loads config/fastdds_large_images.xml when no profile is exported: each node's Fast DDS
    maps its 64 MB segment (the default is 512 KB), so a 9.8 MB points2 goes through shared memory."""
    if any(ros_env.get(name) for name in PROFILE_VARIABLES):
        pytest.skip("a Fast DDS profile is exported here: the user's choice stands")
    for name, process in nodes.items():
        maps = Path(f"/proc/{process.process.pid}/maps").read_text().splitlines()
        segments = {Path(line.split()[-1]) for line in maps if "/dev/shm/fastrtps_" in line}
        sizes = [segment.stat().st_size for segment in segments if segment.exists()]
        assert max(sizes, default=0) >= 64 * 2**20, f"{name}: shared-memory segments of {sizes} bytes"


def test_module_nodes_survived_the_tests(nodes: dict[str, NodeProcess]) -> None:
    for process in nodes.values():
        assert process.process.poll() is None, f"{process.fqn} died:\n{process.output()}"
        assert "Traceback" not in process.output(), process.output()


def calibration_status(diagnostics: Any, after_stamp: int) -> Any:
    """The newest calibration status about a frame stamped at or after `after_stamp`."""
    for array in reversed(diagnostics.messages):
        for status in array.status:
            values = {kv.key: kv.value for kv in status.values}
            if status.name.endswith("calibration") and int(values["frame stamp (ns)"]) >= after_stamp:
                return status, values
    return None


def test_census_core_publishes_confidence_and_the_calibration_check_reports(
    ros: RosHarness, live: dict[str, Any], euroc: Pair
) -> None:
    fqn = "/live/stereo_node"
    confidence = ros.collector(Image, "/live/confidence")
    wait_until(lambda: confidence.subscription.get_publisher_count() >= 1, "confidence matched")
    quality = make_params("quality")
    changes = {
        "matcher": "census_sgm",
        "correlation_window_size": 1,
        "P1": quality.P1,
        "P2": quality.P2,
        "uniqueness_ratio": quality.uniqueness_ratio,
        "calibration_check_every_n_frames": 1,
    }
    assert all(r.successful for r in ros.set_parameters(fqn, **changes))
    try:
        stamp = next(_stamps)
        live["inputs"].publish(euroc, stamp)
        disparity = disparity_from_msg(live["disparity"].wait_stamp(stamp, timeout=120.0))  # numba may compile
        conf = image_to_array(confidence.wait_stamp(stamp))
        assert conf.shape == disparity.shape and conf.dtype == np.float32
        assert conf.min() >= 0.0 and conf.max() <= 1.0
        assert np.all(conf[~np.isfinite(disparity)] == 0.0) and (conf > 0.5).mean() > 0.3

        status, values = wait_until(lambda: calibration_status(live["diagnostics"], stamp), "calibration check")
        assert status.level == DiagnosticStatus.OK, status.message  # the true EuRoC calibration
        assert float(values["median vertical offset (px)"]) < 0.3  # measured 0.14

        # the rig "knocked": the right camera's rectification rotated 0.5 degrees about the baseline
        knocked = Pair(euroc.left, euroc.right, (euroc.left_info, rotated_about_baseline(euroc.right_info, 0.5)))
        stamp = next(_stamps)
        live["inputs"].publish(knocked, stamp)
        status, values = wait_until(lambda: calibration_status(live["diagnostics"], stamp), "calibration check")
        assert status.level == DiagnosticStatus.ERROR, status.message  # 3.9 px: above 1.5 px (README)
        assert "recalibrate" in status.message
    finally:
        restore = {name: getattr(make_params(), name) for name in changes if name != "calibration_check_every_n_frames"}
        ros.set_parameters(fqn, **restore, calibration_check_every_n_frames=30)


def rotated_about_baseline(info: Calibration, degrees: float) -> Calibration:
    angle = np.deg2rad(degrees)
    rotation = np.array([[1, 0, 0], [0, np.cos(angle), -np.sin(angle)], [0, np.sin(angle), np.cos(angle)]])
    return dataclasses.replace(info, r=rotation @ info.r)
