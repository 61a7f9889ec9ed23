"""The nodes' ROS glue without other processes: parameters, QoS rule, rate monitor, worker, YAML."""

from __future__ import annotations

import dataclasses
import fcntl
import json
import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from functools import partial
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
import rclpy
import yaml
from rclpy.executors import SingleThreadedExecutor
from rclpy.lifecycle import LifecycleNode
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import ReliabilityPolicy
from rclpy.serialization import serialize_message
from ros_helpers import wait_until
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, PointCloud2
from std_msgs.msg import Header

from stereo_depth.bag.reader import read_messages
from stereo_depth.core.geometry import Rays
from stereo_depth.core.option_fields import plain_value
from stereo_depth.core.params import PROFILES, StereoParams
from stereo_depth.core.pipeline import StereoPipeline
from stereo_depth.errors import ImageError, MessageError, StereoDepthError
from stereo_depth.formats.scenes import load_scene
from stereo_depth.frames import InputNames, decode_frame, named_errors
from stereo_depth.messages import (
    SerializedMessage,
    array_to_image,
    camera_info_from_msg,
    camera_info_to_msg,
    depth_to_cloud,
    image_to_pipeline,
    make_header,
    same_calibration,
)
from stereo_depth.options import NodeOptions, OutputOptions, Settings
from stereo_depth.options_docs import render_config_yaml
from stereo_depth.ros import problems, serialized_publish
from stereo_depth.ros.diagnostics import NodeDiagnostics, RateMonitor
from stereo_depth.ros.latest_worker import LatestWorker
from stereo_depth.ros.node_main import GIL_SWITCH_S
from stereo_depth.ros.parameters import NodeParameters
from stereo_depth.ros.qos import choose_reliability
from stereo_depth.ros.raw_inputs import raw_reader
from stereo_depth.ros.transport import PROFILE_VARIABLES, use_large_message_profile
from stereo_depth.ros.types import RCLPY_SERIALIZED, RCLPY_TYPES
from stereo_depth.sync import StereoSet, SyncCounters

from conftest import SCENES

CONFIG = Path(__file__).parents[1] / "config" / "stereo_depth.yaml"
BAGS = Path(__file__).parents[1] / "bags"
RELIABLE, BEST_EFFORT = ReliabilityPolicy.RELIABLE, ReliabilityPolicy.BEST_EFFORT


@pytest.fixture
def context(ros_env: dict[str, str]) -> Iterator[rclpy.Context]:
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    yield ctx
    rclpy.try_shutdown(context=ctx)


def node_with(context: rclpy.Context, **overrides: object) -> tuple[Node, NodeParameters, list[Settings]]:
    node = Node(
        "params_under_test",
        context=context,
        parameter_overrides=[Parameter(k, value=v) for k, v in overrides.items()],
        start_parameter_services=False,
    )
    applied: list[Settings] = []
    return node, NodeParameters(node, ("queue_size",), with_stereo=True, on_change=applied.append), applied


def test_profile_gives_the_defaults_and_explicit_values_win(context: rclpy.Context) -> None:
    node, parameters, _ = node_with(context, profile="stereo_image_proc", correlation_window_size=21)
    stereo = parameters.settings.stereo
    assert stereo is not None
    assert stereo.matcher == "bm" and stereo.uniqueness_ratio == PROFILES["stereo_image_proc"]["uniqueness_ratio"]
    assert stereo.correlation_window_size == 21
    assert node.get_parameter("correlation_window_size").value == 21
    node.destroy_node()


def test_stereo_image_proc_alias_sets_matcher_at_start_up(context: rclpy.Context) -> None:
    node, parameters, _ = node_with(context, stereo_algorithm=0)
    assert parameters.settings.stereo is not None and parameters.settings.stereo.matcher == "bm"
    node.destroy_node()


def test_runtime_change_is_validated_against_the_other_values(context: rclpy.Context) -> None:
    node, _, applied = node_with(context)
    [refused] = node.set_parameters([Parameter("P1", value=5000.0)])  # P2 is 800
    assert not refused.successful and "P2 (800.0) must be greater than P1 (5000.0)" in refused.reason
    assert node.get_parameter("P1").value == 200.0 and not applied
    [step] = node.set_parameters([Parameter("disparity_range", value=40)])
    assert not step.successful  # the descriptor's step of 16
    [ok] = node.set_parameters([Parameter("stereo_algorithm", value=0)])
    assert ok.successful and node.get_parameter("matcher").value == "bm"
    assert applied[-1].stereo is not None and applied[-1].stereo.matcher == "bm"
    [read_only] = node.set_parameters([Parameter("profile", value="fast")])
    assert not read_only.successful
    node.destroy_node()


def test_unknown_profile_refuses_to_start(context: rclpy.Context) -> None:
    with pytest.raises(Exception, match="profile 'nope' is unknown"):
        node_with(context, profile="nope")


def test_reliability_follows_the_publishers_like_rosbag2() -> None:
    assert choose_reliability("auto", [RELIABLE, RELIABLE], BEST_EFFORT) == RELIABLE
    assert choose_reliability("auto", [RELIABLE, BEST_EFFORT], RELIABLE) == BEST_EFFORT
    assert choose_reliability("auto", [], BEST_EFFORT) == BEST_EFFORT  # nobody publishes: keep
    assert choose_reliability("reliable", [BEST_EFFORT], BEST_EFFORT) == RELIABLE
    assert choose_reliability("best_effort", [RELIABLE], RELIABLE) == BEST_EFFORT


def test_system_default_qos_means_reliable_unless_forced_otherwise() -> None:
    assert NodeOptions(use_system_default_qos=True).reliability == "reliable"
    assert NodeOptions(use_system_default_qos=True, input_reliability="best_effort").reliability == "best_effort"
    assert NodeOptions().tolerance_ns > 10**18  # 0 s = no limit, as stereo_image_proc


def test_rate_monitor_sees_half_the_frames_missing() -> None:
    monitor = RateMonitor()
    period = 33_000_000
    arrived = [i for i in range(40) if i % 2 == 0 or i % 7 == 0]  # about half, a few consecutive pairs
    for i in arrived:
        monitor.add(i * period, i * 0.033)
    assert monitor.sender_hz() == pytest.approx(1e9 / period)
    assert monitor.missing() == (arrived[-1] - arrived[0] + 1) - len(arrived)


def test_latest_worker_keeps_only_the_newest_waiting_job() -> None:
    started, release = threading.Event(), threading.Event()
    done: list[int] = []
    replaced: list[int] = []

    def run(job: int) -> None:
        started.set()
        release.wait(5)
        done.append(job)

    worker = LatestWorker(run, lambda late: replaced.append(late))
    worker.submit(1)
    started.wait(5)
    for job in (2, 3, 4):
        worker.submit(job)
    release.set()
    wait_until(lambda: len(done) == 2, "the newest job")
    worker.stop()
    assert done == [1, 4] and replaced == [False, False]


@pytest.mark.parametrize("parallel", [1, 2])
def test_latest_worker_runs_at_most_parallel_jobs_at_once(parallel: int) -> None:
    release = threading.Event()
    running: list[int] = []
    most: list[int] = [0]
    lock = threading.Lock()

    def run(job: int) -> None:
        with lock:
            running.append(job)
            most[0] = max(most[0], len(running))
        release.wait(5)
        with lock:
            running.remove(job)

    worker = LatestWorker(run, lambda late: None, capacity=2, threads=2)
    worker.parallel = parallel
    worker.submit(1)
    worker.submit(2)
    wait_until(lambda: len(running) == parallel, f"{parallel} jobs running")
    time.sleep(0.2)  # a job that should wait would have started by now
    assert len(running) == parallel
    release.set()
    worker.stop()
    assert most[0] == parallel


def test_config_yaml_lists_every_parameter_with_its_default() -> None:
    assert CONFIG.read_text() == render_config_yaml(), (
        "config/stereo_depth.yaml is stale: python -m stereo_depth.options_docs yaml > config/stereo_depth.yaml"
    )
    values = yaml.safe_load(CONFIG.read_text())["/**"]["ros__parameters"]
    expected = {"profile": "default"}
    for options in (StereoParams(), NodeOptions(), OutputOptions()):  # a pose as the list a parameter holds
        expected |= {f.name: plain_value(getattr(options, f.name)) for f in dataclasses.fields(options)}
    assert values == expected


def test_our_processes_take_the_large_message_profile_only_when_the_user_chose_none() -> None:
    chosen: dict[str, str] = {}
    profile = use_large_message_profile(chosen)
    assert profile is not None and profile.is_file()
    assert chosen == dict.fromkeys(PROFILE_VARIABLES, str(profile))
    for users in ({"FASTDDS_DEFAULT_PROFILES_FILE": "/mine.xml"}, {"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"}):
        before = dict(users)
        assert use_large_message_profile(users) is None and users == before


def test_diagnostics_count_what_pairing_did_per_topic_and_name_the_bottleneck() -> None:
    topics = ["/l/image_raw", "/l/camera_info", "/r/image_raw", "/r/camera_info"]
    diagnostics = NodeDiagnostics("/stereo_node", topics)

    def report() -> dict[str, str]:
        return {kv.key: kv.value for kv in diagnostics.report(Header()).status[0].values}

    change = SyncCounters(dropped=1, dropped_by_input=[1, 0, 0, 0], substituted=[0, 3, 0, 0], late=[0, 2, 0, 0])
    diagnostics.sync_changed(change)
    diagnostics.add_dropped(1)
    values = report()
    assert values["/l/image_raw unmatched"] == "1" and values["unmatched input messages"] == "1"
    assert values["/l/camera_info missing, last one used"] == "3"
    assert values["/l/camera_info late (after its set)"] == "2"
    assert "/r/camera_info missing, last one used" not in values  # shown once it happens
    bottleneck = values["bottleneck"]
    assert bottleneck.startswith("input /l/camera_info") and "matching slower" in bottleneck
    assert "docs/dds.md#where-frames-go" in bottleneck  # a page that exists (test_docs.py)
    assert report()["bottleneck"] == "none"  # nothing lost since the previous report


def test_rviz_and_foxglove_views_show_what_stereo_node_publishes_in_the_bundled_bags_frame() -> None:
    from stereo_depth.nodes.stereo_node import OUTPUT_TYPES

    rviz = yaml.safe_load((CONFIG.parent / "stereo_depth.rviz").read_text())["Visualization Manager"]
    foxglove = json.loads((CONFIG.parent / "stereo_depth.foxglove.json").read_text())["configById"]
    rviz_topics = {display["Topic"]["Value"] for display in rviz["Displays"] if "Topic" in display}
    foxglove_topics = {panel["imageMode"]["imageTopic"] for panel in foxglove.values() if "imageMode" in panel}
    foxglove_topics |= {topic for panel in foxglove.values() for topic in panel.get("topics", {})}
    shown = {"/stereo/left/image_rect", "/stereo/depth", "/stereo/points2"}
    assert rviz_topics == foxglove_topics == shown and shown <= {f"/stereo/{name}" for name in OUTPUT_TYPES}
    frame = read_messages(BAGS / "middlebury", ["/stereo/left/camera_info"])["/stereo/left/camera_info"][0]
    assert rviz["Global Options"]["Fixed Frame"] == foxglove["3D!cloud"]["followTf"] == frame.header.frame_id


class FakeLogger:
    def __init__(self) -> None:
        self.lines: list[tuple[str, str]] = []

    def warning(self, line: str) -> None:
        self.lines.append(("warning", line))

    def info(self, line: str) -> None:
        self.lines.append(("info", line))


def bad_size(size: int) -> None:
    msg = f"image data has {size} bytes but step x height = 2000"
    raise ImageError(msg)


def refused(log: problems.ProblemLog, convert: Any, *args: Any) -> None:
    """What StereoIONode.guarded does with a frame's error."""
    try:
        convert(*args)
    except StereoDepthError as exc:
        log.skipped(str(exc), problems.error_key(exc))


def named(topic: str, convert: Any, *args: Any) -> None:
    """`convert(*args)` as a node reads its input `topic`."""
    with named_errors(topic):
        convert(*args)


def test_problem_log_gives_one_line_per_kind_and_period_then_counts_the_rest(monkeypatch: pytest.MonkeyPatch) -> None:
    """A flood of one bad input: one line, then one per period saying how many were left out; another
    kind of problem is logged at once. Every refused frame still reaches diagnostics' last error."""
    now = [100.0]
    monkeypatch.setattr(problems, "time", SimpleNamespace(monotonic=lambda: now[0]))
    logger, diagnostics = FakeLogger(), NodeDiagnostics("/n", ["/n/left/image_raw"])
    log = problems.ProblemLog(logger, diagnostics, period_s=5.0)
    for i in range(50):  # 50 frames in 4.9 s; the numbers in the text do not make a new kind
        now[0] = 100.0 + i * 0.1
        refused(log, named, "/n/left/image_raw", bad_size, 1000 + i)
    assert logger.lines == [("warning", "/n/left/image_raw: image data has 1000 bytes but step x height = 2000")]
    assert diagnostics.last_error.startswith("/n/left/image_raw: image data has 1049 bytes")
    log.skipped("/n/right/camera_info: K has no focal length", ("calibration", "/n/right/camera_info"))
    assert logger.lines[-1] == ("warning", "/n/right/camera_info: K has no focal length")  # another kind
    now[0] = 105.0  # one period after the first line
    refused(log, named, "/n/left/image_raw", bad_size, 7)
    assert logger.lines[-1] == (
        "warning",
        "/n/left/image_raw: image data has 7 bytes but step x height = 2000 (49 more like it since the last report)",
    )
    now[0] = 105.1
    log.info("calibration changed", ("calibration", "1"))
    log.info("calibration changed", ("calibration", "2"))  # same text, told apart by the key
    log.info("calibration changed", ("calibration", "1"))
    assert [line for level, line in logger.lines if level == "info"] == ["calibration changed"] * 2
    assert len(logger.lines) == 5


def test_the_same_problem_on_two_cameras_is_two_kinds_though_the_topics_differ_only_in_digits() -> None:
    """A bad image on /rig/cam1 right after one on /rig/cam0: both are logged, each naming its topic."""
    logger, diagnostics = FakeLogger(), NodeDiagnostics("/n", [])
    log = problems.ProblemLog(logger, diagnostics, period_s=5.0)
    good = Image(height=4, width=64, encoding="mono8", step=64, data=bytes(256))
    bad = Image(height=4, width=64, encoding="uyvy", step=128, data=bytes(512))
    names = InputNames("/rig/cam0/image_raw", "/rig/cam0/camera_info", "/rig/cam1/image_raw", "/rig/cam1/camera_info")
    pipeline = StereoPipeline(StereoParams())
    for left, right in ((bad, good), (good, bad)):
        read = partial(decode_frame, rectified=False, names=names)
        refused(log, read, StereoSet(0, left, None, right, None), pipeline, OutputOptions())
    assert [line.split(":")[0] for _, line in logger.lines] == ["/rig/cam0/image_raw", "/rig/cam1/image_raw"]


def test_importing_the_nodes_leaves_signal_handling_alone() -> None:
    """Each node's main installs its Ctrl-C / SIGTERM handlers; importing a node (a launch file, a test,
    a tool) must not change how the importing process handles signals."""
    code = (  # compared with the handlers before the import: a parent may have left SIGINT ignored
        "import signal; before = [signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)]; "
        "import stereo_depth.nodes.stereo_node, stereo_depth.nodes.point_cloud_node; "
        "print(*(signal.getsignal(s) == b for s, b in zip((signal.SIGINT, signal.SIGTERM), before)))"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60)
    assert run.stdout.split() == ["True", "True"], run.stderr


def test_the_signal_handler_takes_no_lock() -> None:
    """Python runs a signal's handler between two bytecodes of the main thread, also inside the handler
    of a signal just before it (a launch file's second SIGTERM, a double Ctrl-C). A handler that takes a
    lock (threading.Event.set) can then wait for itself forever: a node hung so in CI. Every call the
    handler makes is recorded (in a child process: the handler ignores further signals there)."""
    code = (
        "import signal, sys; from stereo_depth.ros import signals; calls = []\n"
        "def record(frame, event, arg):\n"
        "    calls.append(getattr(arg, '__qualname__', '') if event == 'c_call' else frame.f_code.co_qualname)\n"
        "sys.setprofile(record); signals._on_signal(signal.SIGTERM, None); sys.setprofile(None)\n"
        "print(signals.SIGNALLED.is_set(), *sorted({c for c in calls if 'acquire' in c or '__enter__' in c}))"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60)
    assert run.stdout.split() == ["True"], run.stdout + run.stderr


def test_a_node_process_hands_the_gil_over_sooner_than_python_does(tmp_path: Path) -> None:
    """The census core takes the GIL back between its kernels many times a frame; beside the executor's
    Python, Python's 5 ms hand-over made a match several times slower (docs/design/decisions.md). A node's
    main sets the shorter interval before anything else runs (here one that then refuses its params file)."""
    code = (
        "import sys; from stereo_depth.nodes.stereo_node import main; "
        f"code = main(['stereo_node', '--ros-args', '--params-file', '{tmp_path / 'missing.yaml'}']); "
        "print(code, sys.getswitchinterval())"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60)
    assert run.stdout.split() == ["2", str(GIL_SWITCH_S)], run.stdout + run.stderr


@pytest.mark.parametrize("step", ["open_outputs", "start_workers", "_warn_unused_overrides"])
def test_a_start_up_cut_short_ends_every_thread_and_the_node_it_had_started(
    context: rclpy.Context, monkeypatch: pytest.MonkeyPatch, step: str
) -> None:
    """Ctrl-C while numba's kernels load at start-up raises SystemExit in the node's __init__
    (ros/signals.py: interruptible), as may a bad setting its own error. Whatever had started by then
    (the stages' threads, the node in the graph) must end with it, not be left to the interpreter's and
    Fast DDS's teardown at exit."""
    from stereo_depth.nodes.stereo_node import StereoNode  # the import leaves signals alone (test above)

    original = getattr(StereoNode, step)

    def cut_short(node: StereoNode) -> None:
        if step == "start_workers":
            original(node)  # both stages run: the signal comes while the node subscribes
        raise SystemExit(0)

    monkeypatch.setattr(StereoNode, step, cut_short)
    before = set(threading.enumerate())
    with pytest.raises(SystemExit):
        StereoNode(context=context)
    observer = rclpy.create_node("observer", context=context)
    try:
        assert ("stereo_node", "/") not in observer.get_node_names_and_namespaces()
    finally:
        observer.destroy_node()
    left = [t.name for t in set(threading.enumerate()) - before if t.is_alive()]
    assert left == [], left


BENCH = Path(__file__).parents[1] / "bench"


def test_benches_that_talk_dds_take_a_free_domain_id_as_test_runs_do(tmp_path: Path) -> None:
    """No fixed default id (15 was one, unlocked): with every id but 42 held (the locks in a TMPDIR of
    this test's own), a bench settles on 42 and holds it; an exported ROS_DOMAIN_ID stands."""
    held = []
    for domain in range(1, 101):
        if domain != 42:
            lock = (tmp_path / f"stereo_depth_test_domain_{domain}.lock").open("w")
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
            held.append(lock)
    env = {k: v for k, v in os.environ.items() if k != "ROS_DOMAIN_ID"} | {"TMPDIR": str(tmp_path)}

    def bench_domain(extra_env: dict[str, str], then: str = "") -> subprocess.CompletedProcess[str]:
        code = f"from lib import domain_lock; print(domain_lock.isolate_on_this_host()); {then}"
        command = [sys.executable, "-c", code]
        return subprocess.run(command, cwd=BENCH, env=env | extra_env, capture_output=True, text=True, timeout=60)

    claimed = bench_domain({}, then="domain_lock.claim_domain_id()")  # a second claim: 42 is held by now
    assert claimed.stdout.split() == ["42"] and "all 100 ROS domain ids are held" in claimed.stderr
    assert bench_domain({"ROS_DOMAIN_ID": "7"}).stdout.split() == ["7"]
    for bench in ("e2e_dds.py", "soak.py", "cloud_outputs.py"):  # each starts rclpy or nodes
        assert "isolate_on_this_host()" in (BENCH / bench).read_text(), bench


@pytest.mark.parametrize("through_rcl", [True, False])
def test_a_cloud_built_in_its_serialized_bytes_arrives_as_that_cloud(
    context: rclpy.Context, monkeypatch: pytest.MonkeyPatch, through_rcl: bool
) -> None:
    """stereo_node publishes an organized points2 as its CDR bytes through rcl with the GIL released, or
    through rclpy where librcl cannot be loaded: a subscriber gets the cloud either way, and a lifecycle
    publisher sends it only while active."""
    if not through_rcl:
        monkeypatch.setattr(serialized_publish, "_rcl", lambda: None)
    assert (serialized_publish._rcl() is not None) == through_rcl  # librcl loads where rclpy runs
    depth = (1.0 + np.arange(12, dtype=np.float32).reshape(3, 4) / 10).astype(np.float32)
    depth[1, 2] = np.nan
    rays = Rays(x=np.linspace(-0.5, 0.5, 4, dtype=np.float32)[None, :], y=np.array([[-0.2], [0.0], [0.3]], np.float32))
    color = np.full((3, 4, 3), 200, np.uint8)
    header = make_header(RCLPY_TYPES, 1_700_000_000_000_000_001, "cam_left")
    cloud = depth_to_cloud(RCLPY_SERIALIZED, header, depth, rays, color)
    assert isinstance(cloud, SerializedMessage)
    expected = depth_to_cloud(RCLPY_TYPES, header, depth, rays, color)
    node = LifecycleNode("serialized_publish_under_test", context=context, start_parameter_services=False)
    publisher = node.create_lifecycle_publisher(PointCloud2, "points2", 10)
    received: list[Any] = []
    node.create_subscription(PointCloud2, "points2", received.append, 10)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    wait_until(lambda: publisher.get_subscription_count() > 0, "the subscription to match")
    serialized_publish.publish(publisher, cloud)  # inactive: nothing goes out
    publisher.on_activate(None)
    serialized_publish.publish(publisher, cloud)
    deadline = time.monotonic() + 20.0
    while not received and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    for _ in range(20):  # anything the inactive publisher had sent would be here by now
        executor.spin_once(timeout_sec=0.05)
    assert received == [expected], "the cloud published while active, and only that one"
    executor.shutdown()
    node.destroy_node()


def test_inputs_taken_as_their_bytes_read_as_rclpy_reads_them() -> None:
    """The nodes take images and camera_infos raw (stereo_depth/ros/raw_inputs.py): what the reader makes of
    rclpy's bytes decodes to the same pixels and calibration as rclpy's own message, with an rclpy header
    (outputs carry it); bytes cut short are a MessageError that names the type, not a crash."""
    scene = load_scene(SCENES / "artl")
    header = make_header(RCLPY_TYPES, 1_700_000_000_123_456_789, "cam_left")
    image = array_to_image(RCLPY_TYPES, header, scene.left)
    info = camera_info_to_msg(RCLPY_TYPES, header, scene.camera_infos("cam_left")[0])
    info.binning_x, info.roi.x_offset, info.roi.width = 2, 7, 100
    read_image, read_info = raw_reader(Image), raw_reader(CameraInfo)
    assert read_image is not None and read_info is not None and raw_reader(CompressedImage) is None
    image_back, info_back = read_image(serialize_message(image)), read_info(serialize_message(info))
    for back in (image_back, info_back):
        assert isinstance(back.header, Header) and back.header == header
    np.testing.assert_array_equal(image_to_pipeline(image_back), image_to_pipeline(image))
    assert camera_info_from_msg(info_back) == camera_info_from_msg(info)
    assert (info_back.binning_x, info_back.roi.x_offset, info_back.roi.width) == (2, 7, 100)
    assert same_calibration(info_back, info)
    raw = serialize_message(image)
    with pytest.raises(MessageError, match=f"{len(raw) // 2} bytes that are not a sensor_msgs/msg/Image"):
        read_image(raw[: len(raw) // 2])
