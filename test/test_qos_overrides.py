"""rclpy's per-topic QoS overrides on the nodes' inputs and outputs, checked through the ROS graph.

One stereo_node gets `points2` best effort by `-p`, and `disparity` best effort and `left/image_raw`
reliable from a params file; a point_cloud_node (the split chain's nodes share the node base) gets its
`points2` and its `disparity` input best effort. The QoS each endpoint really has is read back with
the graph API, as `ros2 topic info -v` shows it.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator

import pytest
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from ros_helpers import NodeProcess, RosHarness, reliable_qos, wait_until
from sensor_msgs.msg import CompressedImage, Image
from stereo_msgs.msg import DisparityImage

from stereo_depth.ros.node_base import QOS_FULL_RECHECK_S

NS = "/qos"
SPLIT = "/qos_split"
OVERRIDES = "qos_overrides"


@pytest.fixture(scope="module")
def node(ros: RosHarness, ros_env: dict[str, str], tmp_path_factory: pytest.TempPathFactory) -> Iterator[NodeProcess]:
    work = tmp_path_factory.mktemp("qos")
    params = work / "qos.yaml"
    params.write_text(
        "/**:\n  ros__parameters:\n    qos_overrides:\n"
        f"      {NS}/disparity:\n        publisher:\n          reliability: best_effort\n"
        f"      {NS}/left/image_raw:\n        subscription:\n          reliability: reliable\n"
    )
    args = [
        "-p",
        f"{OVERRIDES}.{NS}/points2.publisher.reliability:=best_effort",
        "-p",
        f"{OVERRIDES}.{NS}/point2.publisher.reliability:=best_effort",  # misspelt topic: warned about
        "--params-file",
        str(params),
    ]
    process = NodeProcess("stereo_node", NS, ros_env, work, args)
    split = [
        "-p",
        f"{OVERRIDES}.{SPLIT}/points2.publisher.reliability:=best_effort",
        "-p",
        f"{OVERRIDES}.{SPLIT}/disparity.subscription.reliability:=best_effort",
    ]
    with ros.running([process, NodeProcess("point_cloud_node", SPLIT, ros_env, work, split)]):
        yield process


def publisher_reliability(ros: RosHarness, topic: str, node: str = "stereo_node") -> ReliabilityPolicy | None:
    infos = [i for i in ros.node.get_publishers_info_by_topic(topic) if i.node_name == node]
    return infos[0].qos_profile.reliability if infos else None


def subscription_reliability(ros: RosHarness, topic: str, node: str = "stereo_node") -> ReliabilityPolicy | None:
    infos = [i for i in ros.node.get_subscriptions_info_by_topic(topic) if i.node_name == node]
    return infos[0].qos_profile.reliability if infos else None


def test_output_overrides_reach_the_graph_and_the_others_stay_reliable(ros: RosHarness, node: NodeProcess) -> None:
    del node
    expected = {
        "points2": ReliabilityPolicy.BEST_EFFORT,  # -p
        "disparity": ReliabilityPolicy.BEST_EFFORT,  # params file
        "depth": ReliabilityPolicy.RELIABLE,  # not overridden: our default
        "diagnostics": ReliabilityPolicy.RELIABLE,
    }
    for name, reliability in expected.items():
        wait_until(lambda n=name, r=reliability: publisher_reliability(ros, f"{NS}/{n}") == r, f"{name}: {reliability}")


def test_a_split_node_takes_overrides_on_its_input_and_output(ros: RosHarness, node: NodeProcess) -> None:
    del node
    best_effort = ReliabilityPolicy.BEST_EFFORT
    wait_until(lambda: publisher_reliability(ros, f"{SPLIT}/points2", "point_cloud_node") == best_effort, "points2")
    wait_until(
        lambda: subscription_reliability(ros, f"{SPLIT}/disparity", "point_cloud_node") == best_effort, "disparity"
    )
    camera_info = f"{SPLIT}/left/camera_info"  # not overridden: auto, reliable while nobody publishes
    assert subscription_reliability(ros, camera_info, "point_cloud_node") == ReliabilityPolicy.RELIABLE


def test_input_override_replaces_the_adaptive_rule_for_its_topic_only(ros: RosHarness, node: NodeProcess) -> None:
    """A best-effort camera on both images: right/image_raw (no override) follows it to best effort, as
    by default; left/image_raw stays reliable, as the override says, and the log says so too."""
    left, right = f"{NS}/left/image_raw", f"{NS}/right/image_raw"
    wait_until(lambda: subscription_reliability(ros, left) == ReliabilityPolicy.RELIABLE, "left subscribed")
    cameras = [ros.publisher(Image, topic, ReliabilityPolicy.BEST_EFFORT) for topic in (left, right)]
    try:
        wait_until(lambda: subscription_reliability(ros, right) == ReliabilityPolicy.BEST_EFFORT, "right best effort")
        wait_until(lambda: cameras[1].get_subscription_count() >= 1, "the right camera matched")
        assert subscription_reliability(ros, left) == ReliabilityPolicy.RELIABLE
        wait_until(lambda: f"{right}: subscribed best_effort" in node.output(), "the log line for the right input")
        assert f"{left}: subscribed" not in node.output()
    finally:
        for camera in cameras:
            ros.node.destroy_publisher(camera)


def test_ros2_param_list_shows_every_endpoints_overrides_with_their_values(ros: RosHarness, node: NodeProcess) -> None:
    client = ros._parameter_client(node.fqn)
    future = client.list_parameters([OVERRIDES], 0)
    wait_until(future.done, "list_parameters")
    names = set(future.result().result.names)
    for endpoint in ("points2.publisher", "disparity.publisher", "depth.publisher", "right/camera_info.subscription"):
        for policy in ("history", "depth", "reliability"):
            assert f"{OVERRIDES}.{NS}/{endpoint}.{policy}" in names, (endpoint, policy, sorted(names))
    values = ros.get_parameters(
        node.fqn,
        f"{OVERRIDES}.{NS}/points2.publisher.reliability",
        f"{OVERRIDES}.{NS}/depth.publisher.reliability",
        f"{OVERRIDES}.{NS}/left/image_raw.subscription.reliability",
    )
    assert list(values.values()) == ["best_effort", "reliable", "reliable"]


def test_an_override_for_no_topic_of_the_node_is_named_once_with_the_closest_one(node: NodeProcess) -> None:
    wait_until(lambda: "qos_overrides for no topic" in node.output(), "the start-up warning")
    lines = [line for line in node.output().splitlines() if "qos_overrides for no topic" in line]
    assert len(lines) == 1 and "WARN" in lines[0]
    assert f"'{OVERRIDES}.{NS}/point2.publisher.reliability' (did you mean '" in lines[0]
    assert f"{NS}/points2.publisher.reliability'?)" in lines[0]


def incompatible_lines(node: NodeProcess, topic: str) -> list[str]:
    return [
        line for line in node.output().splitlines() if "requesting incompatible QoS" in line and f"'{topic}'" in line
    ]


@pytest.mark.parametrize(
    ("output", "msg_type", "qos", "policy"),
    [
        ("disparity", DisparityImage, reliable_qos(1), "RELIABILITY"),  # disparity is best effort here
        ("depth", Image, QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL), "DURABILITY"),
    ],  # (our outputs are volatile)
)
def test_a_subscriber_an_output_cannot_serve_is_warned_about_once_with_the_policy(
    ros: RosHarness, node: NodeProcess, output: str, msg_type: type, qos: QoSProfile, policy: str
) -> None:
    """A subscriber asking for QoS the output does not offer gets nothing: the node says so once, in
    rclpy's words, naming the policy (found by looking at the graph: outputs carry no event handlers)."""
    topic = f"{NS}/{output}"
    subscription = ros.node.create_subscription(msg_type, topic, lambda _msg: None, qos)
    try:
        wait_until(lambda: incompatible_lines(node, topic), "the incompatible-QoS warning")
        time.sleep(2 * QOS_FULL_RECHECK_S)  # the node's looks at every endpoint, which warn no second time
        lines = incompatible_lines(node, topic)
        assert len(lines) == 1 and "WARN" in lines[0], lines
        assert f"Last incompatible policy: {policy}" in lines[0], lines[0]
    finally:
        ros.node.destroy_subscription(subscription)


def test_subscribers_an_output_serves_are_not_warned_about(ros: RosHarness, node: NodeProcess) -> None:
    """A viewer or Nav2 subscribing with plain QoS gets the output: no "No messages will be sent" line for it
    (the graph reports their deadline as infinite, the output's creation profile leaves it unset)."""
    topic = f"{NS}/depth"
    before = incompatible_lines(node, topic)  # another test's subscriber may have been warned about
    qos_profiles = (1, reliable_qos(10))
    subscriptions = [ros.node.create_subscription(Image, topic, lambda _msg: None, qos) for qos in qos_profiles]
    try:
        wait_until(lambda: ros.node.count_publishers(topic) == 1, "the output in the graph")
        time.sleep(2 * QOS_FULL_RECHECK_S)  # the node looks at every subscription within one full recheck
        assert incompatible_lines(node, topic) == before
    finally:
        for subscription in subscriptions:
            ros.node.destroy_subscription(subscription)


def test_a_publisher_of_another_type_on_an_input_is_warned_about_once_with_both_types(
    ros: RosHarness, node: NodeProcess
) -> None:
    """A compressed stream published on right/image_raw never matches the node's Image subscription: the
    node names the topic and both types once, and its subscription stays as the Image publishers want it."""
    topic = f"{NS}/right/image_raw"
    before = subscription_reliability(ros, topic)
    other = ReliabilityPolicy.BEST_EFFORT if before == ReliabilityPolicy.RELIABLE else ReliabilityPolicy.RELIABLE
    wrong = ros.publisher(CompressedImage, topic, other)  # an Image publisher offering this would move it
    try:
        expected = f"Incompatible type on topic '{topic}': a publisher sends sensor_msgs/msg/CompressedImage"
        wait_until(lambda: expected in node.output(), "the incompatible-type warning")
        time.sleep(2 * QOS_FULL_RECHECK_S)
        lines = [line for line in node.output().splitlines() if expected in line]
        assert len(lines) == 1 and "WARN" in lines[0] and "this node takes sensor_msgs/msg/Image" in lines[0], lines
        assert subscription_reliability(ros, topic) == before
    finally:
        ros.node.destroy_publisher(wrong)


def test_an_override_value_rclpy_cannot_apply_stops_the_node_with_the_reason(
    start_node: Callable[..., NodeProcess],
) -> None:
    process = start_node("stereo_node", "/bad", ["-p", f"{OVERRIDES}./bad/points2.publisher.reliability:=sometimes"])
    code = process.process.wait(timeout=120)
    output = process.output()
    assert code == 2, output
    assert "cannot start" in output and "reliability" in output and "sometimes" in output, output
    assert "Traceback" not in output, output
