"""stereo_lifecycle_node driven through its transitions over real DDS, by the lifecycle services a
manager (nav2_lifecycle_manager, `ros2 lifecycle set`) calls: what exists and what is published in
each state, the way back from a failed transition, and a clean exit from every state."""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from lifecycle_msgs.msg import Transition, TransitionEvent
from lifecycle_msgs.srv import ChangeState, GetState
from rcl_interfaces.srv import ListParameters
from rclpy.qos import ReliabilityPolicy
from ros_helpers import Collector, NodeProcess, RosHarness, stop_all, wait_until
from sensor_msgs.msg import Image, PointCloud2
from stereo_msgs.msg import DisparityImage
from test_nodes import Pair, StereoInput, euroc_pair
from test_qos_overrides import publisher_reliability, subscription_reliability

from stereo_depth.core.params import StereoParams
from stereo_depth.formats.camera_info_yaml import camera_info_to_yaml
from stereo_depth.frames.registered import REGISTERED_OUTPUTS
from stereo_depth.nodes.stereo_node import OUTPUT_TYPES, StereoNode

NODE = "stereo_lifecycle_node"
INPUTS = ("left/image_raw", "left/camera_info", "right/image_raw", "right/camera_info")
QUIET_S = 3.0  # how long an output must stay silent to count as "not published" (diagnostics: 1 Hz)
_stamps = itertools.count(1_800_000_000 * 10**9, 500_000_000)


class Managed:
    """One stereo_lifecycle_node process and the services and topics a lifecycle manager uses."""

    def __init__(self, ros: RosHarness, process: NodeProcess) -> None:
        self.ros, self.process, self.ns = ros, process, process.namespace
        node = ros.node
        self._change = node.create_client(ChangeState, f"{process.fqn}/change_state")
        self._get = node.create_client(GetState, f"{process.fqn}/get_state")
        self.events: list[TransitionEvent] = []
        self._events = node.create_subscription(
            TransitionEvent, f"{process.fqn}/transition_event", self.events.append, 10
        )
        ros.wait_for_nodes([process])
        for client in (self._change, self._get):
            assert client.wait_for_service(timeout_sec=20.0), f"{client.srv_name} not offered"

    def change(self, transition: int) -> bool:
        future = self._change.call_async(ChangeState.Request(transition=Transition(id=transition)))
        return bool(wait_until(future.done, f"transition {transition}", timeout=60.0) and future.result().success)

    def state(self) -> str:
        future = self._get.call_async(GetState.Request())
        wait_until(future.done, "get_state")
        return str(future.result().current_state.label)

    def publishers(self, topic: str) -> int:
        return self.ros.node.count_publishers(f"{self.ns}/{topic}")

    def subscriptions(self, topic: str) -> int:
        return self.ros.node.count_subscribers(f"{self.ns}/{topic}")

    def wait_inputs(self, count: int) -> None:
        for topic in INPUTS:
            wait_until(lambda t=topic: self.subscriptions(t) == count, f"{count} subscriptions on {topic}")

    def wait_outputs(self, count: int) -> None:
        """Registered depth's outputs exist only with rgb_in_left set: never here."""
        for topic in (*OUTPUT_TYPES, "diagnostics"):
            expected = 0 if topic in REGISTERED_OUTPUTS else count
            wait_until(lambda t=topic, n=expected: self.publishers(t) == n, f"{expected} publishers of {topic}")


@pytest.fixture(scope="module")
def pair() -> Pair:
    return euroc_pair()


@pytest.fixture
def start(ros: RosHarness, start_node: Callable[..., NodeProcess]) -> Callable[..., Managed]:
    """Starts a stereo_lifecycle_node under `namespace` with `args` (stopped at the test's end, whatever
    happened) and waits for its lifecycle services."""
    return lambda namespace, *args: Managed(ros, start_node(NODE, namespace, args))


def quiet(collector: Collector, seconds: float = QUIET_S) -> bool:
    """Nothing arrives on `collector` for `seconds` (a negative check has to wait for something)."""
    before = len(collector.messages)
    time.sleep(seconds)
    return len(collector.messages) == before


def frame_through(
    managed: Managed, inputs: StereoInput, pair: Pair, disparity: Collector, points: Collector, infos: int = 1
) -> int:
    """One frame in, its disparity and cloud out (`infos`: 0 when camera_info comes from files)."""
    inputs.wait_matched(infos=infos)
    stamp = next(_stamps)
    inputs.publish(pair, stamp)
    disparity.wait_stamp(stamp, timeout=60.0)
    points.wait_stamp(stamp, timeout=60.0)
    return stamp


@pytest.mark.parametrize("executor", ["standard", "events"])
def test_full_cycle_publishes_only_while_active_and_releases_on_deactivate_and_cleanup(
    ros: RosHarness, start: Callable[..., Managed], pair: Pair, executor: str
) -> None:
    managed = start(f"/cycle_{executor}", "-p", f"executor:={executor}")
    ns = managed.ns
    disparity = ros.collector(DisparityImage, f"{ns}/disparity")
    points = ros.collector(PointCloud2, f"{ns}/points2")
    diagnostics = ros.collector(DiagnosticArray, f"{ns}/diagnostics")
    inputs = StereoInput(ros, ns)

    # unconfigured: stereo_node's parameters, nothing else
    assert managed.state() == "unconfigured"
    listed = ros.node.create_client(ListParameters, f"{managed.process.fqn}/list_parameters")
    assert listed.wait_for_service(timeout_sec=20.0)
    future = listed.call_async(ListParameters.Request())
    names = set(wait_until(future.done, "list_parameters") and future.result().result.names)
    expected = {"profile", *StereoNode.OPTIONS, *StereoParams.__dataclass_fields__}
    assert expected <= names, sorted(expected - names)
    managed.wait_outputs(0)
    managed.wait_inputs(0)
    assert "unconfigured: parameters declared" in managed.process.output()

    assert managed.change(Transition.TRANSITION_CONFIGURE)
    assert managed.state() == "inactive"
    managed.wait_outputs(1)
    managed.wait_inputs(0)
    assert quiet(diagnostics)

    for _ in range(2):  # activate, deactivate twice: the second activation starts from released inputs
        assert managed.change(Transition.TRANSITION_ACTIVATE)
        assert managed.state() == "active"
        managed.wait_inputs(1)
        frame_through(managed, inputs, pair, disparity, points)
        diagnostics.wait_any()

        assert managed.change(Transition.TRANSITION_DEACTIVATE)
        assert managed.state() == "inactive"
        managed.wait_inputs(0)
        managed.wait_outputs(1)
        silent = next(_stamps)
        inputs.publish(pair, silent)  # nobody subscribes: nothing can come of it
        assert quiet(diagnostics)
        assert silent not in disparity.stamps()

    assert managed.change(Transition.TRANSITION_CLEANUP)
    assert managed.state() == "unconfigured"
    managed.wait_outputs(0)
    managed.wait_inputs(0)

    assert managed.change(Transition.TRANSITION_UNCONFIGURED_SHUTDOWN)
    assert managed.state() == "finalized"
    wait_until(lambda: len(managed.events) >= 14, "transition events")  # each: to the transition state, then on
    goals = [event.goal_state.label for event in managed.events if event.goal_state.id < 10]  # primary states
    assert goals == ["inactive", "active", "inactive", "active", "inactive", "unconfigured", "finalized"]

    results = stop_all([managed.process])  # from finalized: exit 0, no traceback
    log = results[managed.process.fqn][1]
    publishers = len(set(OUTPUT_TYPES) - set(REGISTERED_OUTPUTS)) + 1  # and diagnostics; no rgb_in_left
    for line in (
        f"configure: done, matcher built, {publishers} publishers, 0 subscriptions, workers stopped",
        f"activate: done, matcher built, {publishers} publishers, 4 subscriptions, workers running",
        f"deactivate: done, matcher built, {publishers} publishers, 0 subscriptions, workers stopped",
        "cleanup: done, matcher none, 0 publishers, 0 subscriptions, workers stopped",
        "shutdown: done, matcher none, 0 publishers, 0 subscriptions, workers stopped",
    ):
        assert line in log, log


def test_a_failed_configure_goes_through_errorprocessing_back_to_unconfigured(
    start: Callable[..., Managed], tmp_path: Path
) -> None:
    missing = tmp_path / "missing.yaml"
    managed = start("/failing", "-p", f"left_camera_info_url:=file://{missing}")
    assert not managed.change(Transition.TRANSITION_CONFIGURE)
    assert managed.state() == "unconfigured"
    wait_until(lambda: len(managed.events) >= 3, "transition events")
    labels = [(e.start_state.label, e.goal_state.label) for e in managed.events]
    assert labels == [
        ("unconfigured", "configuring"),
        ("configuring", "errorprocessing"),
        ("errorprocessing", "unconfigured"),
    ]
    output = managed.process.output()
    assert "configure failed: left_camera_info_url" in output and str(missing) in output, output
    assert "error processing (after a failed transition from unconfigured)" in output, output
    managed.wait_outputs(0)
    stop_all([managed.process])


def test_configure_succeeds_once_the_cause_of_a_failed_one_is_fixed_and_frames_flow(
    ros: RosHarness, start: Callable[..., Managed], tmp_path: Path, pair: Pair
) -> None:
    """What the errorprocessing log line promises: after a failed configure the node is unconfigured and
    whole, and configures once the cause is fixed. The camera_info URLs are start-up parameters (read-only),
    so the fix is the file the parameter names, as a user would fix it, not a new URL."""
    left, right = tmp_path / "left.yaml", tmp_path / "right.yaml"
    left.write_text("image_width: [not, a calibration\n")
    right.write_text(camera_info_to_yaml(pair.right_info, "right"))
    urls = ("-p", f"left_camera_info_url:=file://{left}", "-p", f"right_camera_info_url:=file://{right}")
    managed = start("/fixed", *urls)
    assert not managed.change(Transition.TRANSITION_CONFIGURE)
    assert managed.state() == "unconfigured"
    assert "configure failed: left_camera_info_url" in managed.process.output(), managed.process.output()

    left.write_text(camera_info_to_yaml(pair.left_info, "left"))
    assert managed.change(Transition.TRANSITION_CONFIGURE), managed.process.output()
    assert managed.change(Transition.TRANSITION_ACTIVATE)
    assert managed.state() == "active"
    disparity = ros.collector(DisparityImage, f"{managed.ns}/disparity")
    points = ros.collector(PointCloud2, f"{managed.ns}/points2")
    frame_through(managed, StereoInput(ros, managed.ns), pair, disparity, points, infos=0)


def test_qos_overrides_hold_after_deactivate_and_activate(ros: RosHarness, start: Callable[..., Managed]) -> None:
    """Deactivate destroys the inputs and activate creates them anew: each time they take the overrides
    given at start-up again (left/image_raw best effort though its camera offers reliable: the override
    beats the adaptive rule), the outputs keep theirs, and right/image_raw, not overridden, still follows
    its best-effort camera."""
    ns = "/qos_cycle"
    managed = start(
        ns,
        "-p",
        f"qos_overrides.{ns}/points2.publisher.reliability:=best_effort",
        "-p",
        f"qos_overrides.{ns}/left/image_raw.subscription.reliability:=best_effort",
    )
    cameras = [
        ros.publisher(Image, f"{ns}/left/image_raw", ReliabilityPolicy.RELIABLE),
        ros.publisher(Image, f"{ns}/right/image_raw", ReliabilityPolicy.BEST_EFFORT),
    ]
    best_effort, reliable = ReliabilityPolicy.BEST_EFFORT, ReliabilityPolicy.RELIABLE
    expected = {
        f"{ns}/points2": (publisher_reliability, best_effort),
        f"{ns}/depth": (publisher_reliability, reliable),
        f"{ns}/left/image_raw": (subscription_reliability, best_effort),
        f"{ns}/right/image_raw": (subscription_reliability, best_effort),
    }
    try:
        assert managed.change(Transition.TRANSITION_CONFIGURE)
        for activation in ("first", "second"):
            assert managed.change(Transition.TRANSITION_ACTIVATE)
            for topic, (reliability, want) in expected.items():
                wait_until(
                    lambda t=topic, r=reliability, w=want: r(ros, t, NODE) == w,
                    f"{topic} {want.name.lower()} after the {activation} activation",
                )
            assert managed.change(Transition.TRANSITION_DEACTIVATE)
            managed.wait_inputs(0)
    finally:
        for camera in cameras:
            ros.node.destroy_publisher(camera)


def test_sigint_ends_the_node_cleanly_from_every_state(
    ros: RosHarness, start: Callable[..., Managed], pair: Pair
) -> None:
    """Unconfigured, inactive, and active while frames flow: exit code 0, no traceback (stop_all)."""
    nodes = {label: start(f"/sigint_{label}") for label in ("unconfigured", "inactive", "active")}
    assert nodes["inactive"].change(Transition.TRANSITION_CONFIGURE)
    active = nodes["active"]
    assert active.change(Transition.TRANSITION_CONFIGURE) and active.change(Transition.TRANSITION_ACTIVATE)
    for label, managed in nodes.items():
        assert managed.state() == label
    disparity = ros.collector(DisparityImage, f"{active.ns}/disparity")
    points = ros.collector(PointCloud2, f"{active.ns}/points2")
    inputs = StereoInput(ros, active.ns)
    frame_through(active, inputs, pair, disparity, points)
    inputs.publish(pair, next(_stamps))  # a frame in flight when the signal comes
    stop_all([managed.process for managed in nodes.values()])


def test_shutdown_from_inactive_and_from_active_releases_everything(
    ros: RosHarness, start: Callable[..., Managed], pair: Pair
) -> None:
    inactive = start("/shutdown_inactive")
    active = start("/shutdown_active")
    assert inactive.change(Transition.TRANSITION_CONFIGURE)
    assert active.change(Transition.TRANSITION_CONFIGURE) and active.change(Transition.TRANSITION_ACTIVATE)
    disparity = ros.collector(DisparityImage, f"{active.ns}/disparity")
    points = ros.collector(PointCloud2, f"{active.ns}/points2")
    frame_through(active, StereoInput(ros, active.ns), pair, disparity, points)

    assert inactive.change(Transition.TRANSITION_INACTIVE_SHUTDOWN)
    assert active.change(Transition.TRANSITION_ACTIVE_SHUTDOWN)
    for managed in (inactive, active):
        assert managed.state() == "finalized"
        managed.wait_inputs(0)
        managed.wait_outputs(0)
        assert (
            "shutdown: done, matcher none, 0 publishers, 0 subscriptions, workers stopped" in managed.process.output()
        )
    stop_all([inactive.process, active.process])
