"""Bad live input, one case per test: stereo_node says what is wrong on which topic, in its log and in
diagnostics, skips the frame, stays up, and gives the next good frame exactly the offline disparity.

One stereo_node (/faults) serves the whole module. Each case publishes its bad set, waits for the
node to report it, then publishes the good artl pair and compares the disparity bit for bit.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.parameter import Parameter
from rclpy.serialization import serialize_message
from ros_helpers import NodeProcess, RosHarness, wait_until
from sensor_msgs.msg import CameraInfo, Image
from stereo_msgs.msg import DisparityImage

from stereo_depth.core.camera import CameraInfo as Calibration
from stereo_depth.core.params import make_params
from stereo_depth.core.pipeline import StereoPipeline
from stereo_depth.formats.scenes import load_scene
from stereo_depth.messages import (
    array_to_image,
    camera_info_from_msg,
    camera_info_to_msg,
    disparity_to_msg,
    image_to_pipeline,
    make_header,
)
from stereo_depth.ros import problems
from stereo_depth.ros.types import RCLPY_TYPES

from conftest import SCENES

NS = "/faults"
FRAME = "camera_left_optical_frame"
TOPICS = [f"{NS}/left/image_raw", f"{NS}/left/camera_info", f"{NS}/right/image_raw", f"{NS}/right/camera_info"]
LEFT_IMAGE, LEFT_INFO, RIGHT_IMAGE, RIGHT_INFO = range(4)
_stamps = itertools.count(1_750_000_000 * 10**9, 100_000_000)
Messages = list[Any]  # left image, left info, right image, right info (rclpy messages)


class Scene:
    """The artl pair and its calibration, as messages and as the offline pipeline's result."""

    def __init__(self) -> None:
        scene = load_scene(SCENES / "artl")
        self.left, self.right = scene.left, scene.right
        self.infos: tuple[Calibration, Calibration] = scene.camera_infos(FRAME)

    def messages(self, stamp: int, infos: tuple[Calibration, Calibration] | None = None) -> Messages:
        header = make_header(RCLPY_TYPES, stamp, FRAME)
        left_info, right_info = infos or self.infos
        return [
            array_to_image(RCLPY_TYPES, header, self.left),
            camera_info_to_msg(RCLPY_TYPES, header, left_info),
            array_to_image(RCLPY_TYPES, header, self.right),
            camera_info_to_msg(RCLPY_TYPES, header, right_info),
        ]

    def disparity_bytes(self, messages: Messages) -> bytes:
        """What `stereo-depth process` would put in the DisparityImage for these very messages."""
        pipeline = StereoPipeline(make_params())
        camera = pipeline.camera_for(camera_info_from_msg(messages[1]), camera_info_from_msg(messages[3]))
        result = pipeline.process(image_to_pipeline(messages[0]), image_to_pipeline(messages[2]), camera)
        header = make_header(RCLPY_TYPES, 0, FRAME)
        return bytes(disparity_to_msg(RCLPY_TYPES, header, result.disparity, camera, 0, 64, (0, 0, 0, 0)).image.data)


class FaultyNode:
    """The node under test, its inputs, and what it said (log, diagnostics, disparity)."""

    def __init__(self, ros: RosHarness, process: NodeProcess, scene: Scene) -> None:
        self.ros, self.process, self.scene = ros, process, scene
        self.publishers = [ros.publisher(Image if i % 2 == 0 else CameraInfo, t) for i, t in enumerate(TOPICS)]
        self.disparity = ros.collector(DisparityImage, f"{NS}/disparity")
        self.diagnostics = ros.collector(DiagnosticArray, f"{NS}/diagnostics")
        for collector in (self.disparity, self.diagnostics):
            wait_until(lambda c=collector: c.subscription.get_publisher_count() >= 1, "outputs matched")
        for publisher in self.publishers:
            wait_until(lambda p=publisher: p.get_subscription_count() >= 1, f"{publisher.topic_name} matched")
        self.good_bytes = scene.disparity_bytes(scene.messages(0))

    def publish(self, messages: Messages, only: tuple[int, ...] = (0, 1, 2, 3)) -> None:
        for index in only:
            self.publishers[index].publish(messages[index])

    def log_mark(self) -> int:
        return len(self.process.output())

    def wait_log(self, mark: int, *parts: str) -> str:
        """The first line logged after `mark` that contains every part."""

        def find() -> str | None:
            lines = self.process.output()[mark:].splitlines()
            return next((line for line in lines if all(p in line for p in parts)), None)

        line: str = wait_until(find, f"a log line with {parts}")
        return line

    def wait_diagnostics(self, since: int, key: str, *parts: str) -> dict[str, str]:
        """Values of the first diagnostics message after index `since` whose `key` has every part."""

        def find() -> dict[str, str] | None:
            for array in self.diagnostics.messages[since:]:
                values = {kv.key: kv.value for kv in array.status[0].values}
                if key in values and all(p in values[key] for p in parts):
                    return values
            return None

        values: dict[str, str] = wait_until(find, f"diagnostics '{key}' with {parts}")
        return values

    def good_frame_is_exact(self) -> None:
        """The node is alive and turns the next good set into exactly the offline disparity."""
        assert self.process.process.poll() is None, self.process.output()
        stamp = next(_stamps)
        self.publish(self.scene.messages(stamp))
        assert bytes(self.disparity.wait_stamp(stamp).image.data) == self.good_bytes

    def refuses(self, messages: Messages, *parts: str, good_next: bool = True, logged: bool = True) -> str:
        """Publish a bad set; assert it is logged (unless the same kind of problem was, less than a
        throttle period ago) and in diagnostics (with every part), skipped, survived."""
        mark, since = self.log_mark(), len(self.diagnostics.messages)
        published = self.disparity.stamps().count(stamp_of(messages))
        self.publish(messages)
        line = self.wait_log(mark, *parts) if logged else ""
        self.wait_diagnostics(since, "last error", *parts)
        if good_next:
            self.good_frame_is_exact()
        assert self.disparity.stamps().count(stamp_of(messages)) == published, "the bad frame was published"
        return line


@pytest.fixture(scope="module")
def node(ros: RosHarness, ros_env: dict[str, str], tmp_path_factory: pytest.TempPathFactory) -> Iterator[FaultyNode]:
    process = NodeProcess("stereo_node", NS, ros_env, tmp_path_factory.mktemp("faults"))
    with ros.running([process]):
        yield FaultyNode(ros, process, Scene())


def bad(scene: Scene, change: Callable[[Messages], None]) -> Messages:
    messages = scene.messages(next(_stamps))
    change(messages)
    return messages


def resized(image: Image, width: int, height: int) -> Image:
    """The same message with its picture resized (its own header kept)."""
    pixels = cv2.resize(image_to_pipeline(image), (width, height))
    return array_to_image(RCLPY_TYPES, image.header, pixels)


def set_info(index: int, **fields: Any) -> Callable[[Messages], None]:
    def change(messages: Messages) -> None:
        for name, value in fields.items():
            setattr(messages[index], name, value)

    return change


def p_with(info: Calibration, row: int, col: int, value: float) -> np.ndarray:
    p = info.p.copy()
    p[row, col] = value
    return p.ravel()


# ------------------------------------------------------------------ sizes


def test_left_and_right_of_different_sizes(node: FaultyNode) -> None:
    def right_smaller(m: Messages) -> None:
        m[RIGHT_IMAGE] = resized(m[RIGHT_IMAGE], 320, 240)

    node.refuses(bad(node.scene, right_smaller), f"{NS}/left/image_raw is 347x277 but {NS}/right/image_raw is 320x240")


def test_camera_info_size_different_from_its_image(node: FaultyNode) -> None:
    def vga_infos(m: Messages) -> None:
        for i in (LEFT_INFO, RIGHT_INFO):
            set_info(i, width=640, height=480)(m)

    messages = bad(node.scene, vga_infos)
    line = node.refuses(messages, f"{NS}/left/camera_info", "say 640x480", "publish the calibration of this")
    assert "347x277" in line


def test_images_too_small_to_match_are_refused_not_crashed_on(node: FaultyNode) -> None:
    def tiny(m: Messages) -> None:
        m[LEFT_IMAGE], m[RIGHT_IMAGE] = resized(m[LEFT_IMAGE], 40, 30), resized(m[RIGHT_IMAGE], 40, 30)
        for i in (LEFT_INFO, RIGHT_INFO):
            m[i].width, m[i].height = 40, 30

    node.refuses(bad(node.scene, tiny), f"{NS}/left/image_raw and {NS}/right/image_raw", "too small to match")


# ------------------------------------------------------------------ calibration


@pytest.mark.parametrize(
    ("index", "field", "value", "reason"),
    [
        (LEFT_INFO, "k", np.zeros(9), "left camera_info: K has no focal length"),
        (RIGHT_INFO, "p", np.zeros(12), "right camera_info: P has no focal length"),
        (LEFT_INFO, "k", np.array([np.nan, 0, 170, 0, 1, 140, 0, 0, 1.0]), "left camera_info: K contains NaN or inf"),
        (RIGHT_INFO, "d", np.array([0.0, np.inf, 0, 0, 0]), "right camera_info: D contains NaN or inf"),
        (LEFT_INFO, "distortion_model", "fancy_model", "unknown distortion model 'fancy_model'"),
    ],
    ids=["zero K", "zero P", "NaN in K", "inf in D", "unknown distortion model"],
)
def test_unusable_camera_info(node: FaultyNode, index: int, field: str, value: Any, reason: str) -> None:
    changes = {field: value}
    if field == "distortion_model":
        changes["d"] = np.array([0.1, 0.0, 0.0, 0.0, 0.0])  # a model we do not know, with real coefficients
    messages = bad(node.scene, set_info(index, **changes))
    node.refuses(messages, reason, f"{NS}/left/camera_info", f"{NS}/right/camera_info")


def test_right_camera_on_the_left(node: FaultyNode) -> None:
    right = node.scene.infos[1]
    p = p_with(right, 0, 3, -right.p[0, 3])
    node.refuses(bad(node.scene, set_info(RIGHT_INFO, p=p)), "to the LEFT of the left camera", "swapped")


def test_calibration_changing_mid_stream_rebuilds_the_maps_once(node: FaultyNode) -> None:
    left, right = node.scene.infos
    distorted = Calibration.from_values(
        left.width, left.height, left.k, [0.05, -0.01, 0.0, 0.0, 0.0], left.r, left.p, "plumb_bob", FRAME
    )

    def calibrations_loaded() -> int:
        since = len(node.diagnostics.messages)
        return int(node.wait_diagnostics(since, "calibrations loaded")["calibrations loaded"])

    node.good_frame_is_exact()
    before, mark = calibrations_loaded(), node.log_mark()
    for _ in range(3):
        messages = node.scene.messages(next(_stamps), (distorted, right))
        node.publish(messages)
        received = node.disparity.wait_stamp(stamp_of(messages))
        assert bytes(received.image.data) == node.scene.disparity_bytes(messages)
        assert bytes(received.image.data) != node.good_bytes  # the new maps are in use
    assert calibrations_loaded() == before + 1
    node.wait_log(mark, "calibration changed", f"{NS}/left/camera_info", "rectification maps rebuilt")
    node.good_frame_is_exact()
    assert calibrations_loaded() == before + 2


# ------------------------------------------------------------------ encodings

BAYER = {"rggb": "RGGB", "bggr": "BGGR", "gbrg": "GBRG", "grbg": "GRBG"}


def mosaic(bgr: np.ndarray, pattern: str) -> np.ndarray:
    """What a colour sensor with this Bayer pattern (e.g. 'rggb': R at (0,0)) records of the scene."""
    channel = {"b": 0, "g": 1, "r": 2}
    out = np.empty(bgr.shape[:2], bgr.dtype)
    for (dy, dx), colour in zip(((0, 0), (0, 1), (1, 0), (1, 1)), pattern, strict=True):
        out[dy::2, dx::2] = bgr[dy::2, dx::2, channel[colour]]
    return out


def encode(image: Image, encoding: str) -> Image:
    """The message as a camera publishing `encoding` sends the same picture."""
    bgr = image_to_pipeline(image)
    big_endian = encoding.endswith("_be")
    encoding = encoding.removesuffix("_be")
    conversions = {"rgb8": cv2.COLOR_BGR2RGB, "rgba8": cv2.COLOR_BGR2RGBA, "bgra8": cv2.COLOR_BGR2BGRA}
    if encoding in conversions:
        pixels = cv2.cvtColor(bgr, conversions[encoding])
    elif encoding.startswith("mono"):
        pixels = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    elif encoding.startswith("bayer_"):
        pixels = mosaic(bgr, encoding[6:10])
    else:
        pixels = bgr
    if encoding.endswith("16"):
        pixels = pixels.astype(np.uint16) * 257
    data = pixels.astype(pixels.dtype.newbyteorder(">")) if big_endian else pixels
    step = pixels.shape[1] * pixels.itemsize * (pixels.shape[2] if pixels.ndim == 3 else 1)
    return Image(
        header=image.header,
        height=pixels.shape[0],
        width=pixels.shape[1],
        encoding=encoding,
        is_bigendian=int(big_endian),
        step=step,
        data=data.tobytes(),
    )


CAMERA_ENCODINGS = [
    "mono8",
    "mono16",
    "mono16_be",
    "bgr8",
    "rgb8",
    "bgra8",
    "rgba8",
    "rgb16",
    *(f"bayer_{p}8" for p in BAYER),
    "bayer_rggb16",
    "bayer_grbg16_be",
]


@pytest.mark.parametrize("encoding", CAMERA_ENCODINGS)
def test_every_stereo_camera_encoding_gives_the_offline_disparity(node: FaultyNode, encoding: str) -> None:
    messages = node.scene.messages(next(_stamps))
    for i in (LEFT_IMAGE, RIGHT_IMAGE):
        messages[i] = encode(messages[i], encoding)
    node.publish(messages)
    received = node.disparity.wait_stamp(stamp_of(messages))
    assert bytes(received.image.data) == node.scene.disparity_bytes(messages)
    if encoding in ("bgr8", "rgb8", "bgra8", "rgba8"):  # lossless: exactly the colour pair's result
        assert bytes(received.image.data) == node.good_bytes


@pytest.mark.parametrize(("left", "right"), [("rgb8", "mono8"), ("mono16", "mono8"), ("bgr8", "bayer_rggb8")])
def test_left_and_right_in_different_encodings(node: FaultyNode, left: str, right: str) -> None:
    messages = node.scene.messages(next(_stamps))
    messages[LEFT_IMAGE] = encode(messages[LEFT_IMAGE], left)
    messages[RIGHT_IMAGE] = encode(messages[RIGHT_IMAGE], right)
    node.publish(messages)
    received = node.disparity.wait_stamp(stamp_of(messages))
    assert bytes(received.image.data) == node.scene.disparity_bytes(messages)
    assert np.isfinite(np.frombuffer(bytes(received.image.data), np.float32)).all()


@pytest.mark.parametrize(
    ("encoding", "reason"),
    [
        ("yuv422", "'yuv422' is not supported"),
        ("32FC1", "'32FC1' is not supported"),
        ("jpeg", "'jpeg' is not supported"),
        ("", "empty encoding"),
    ],
)
def test_other_encodings_are_refused_by_name(node: FaultyNode, encoding: str, reason: str) -> None:
    """Each is in diagnostics; unsupported encodings are one kind of problem, so the log names the first
    of them and counts the rest within the period."""
    node.refuses(bad(node.scene, set_info(LEFT_IMAGE, encoding=encoding)), f"{NS}/left/image_raw", reason, logged=False)
    logged = f"{NS}/left/image_raw: image " + ("has an empty encoding" if not encoding else "encoding '")
    wait_until(lambda: logged in node.process.output(), f"a log line with {logged!r}")


# ------------------------------------------------------------------ buffers


def test_buffer_shorter_than_step_times_height(node: FaultyNode) -> None:
    def truncate(m: Messages) -> None:
        m[RIGHT_IMAGE].data = bytes(m[RIGHT_IMAGE].data)[:-7]

    node.refuses(bad(node.scene, truncate), f"{NS}/right/image_raw", "bytes but step x height")


def test_message_bytes_cut_short_are_skipped_naming_the_topic(node: FaultyNode) -> None:
    """A sender that publishes serialized bytes (rclpy's publish(bytes), a bridge) and cuts an image short:
    the node takes its inputs raw, says which topic sent what, and pairs the next good set."""

    def cut(m: Messages) -> None:
        raw = serialize_message(m[RIGHT_IMAGE])
        m[RIGHT_IMAGE] = raw[: len(raw) // 2]

    messages = bad(node.scene, cut)
    parts = (f"{NS}/right/image_raw", f"{len(messages[RIGHT_IMAGE])} bytes that are not a sensor_msgs/msg/Image")
    node.refuses(messages, *parts)


def test_step_smaller_than_a_row(node: FaultyNode) -> None:
    def short_step(m: Messages) -> None:
        image = m[LEFT_IMAGE]
        image.step -= 3
        image.data = bytes(image.data)[: image.step * image.height]

    node.refuses(bad(node.scene, short_step), f"{NS}/left/image_raw", "smaller than one row")


def test_rows_padded_beyond_the_width_are_read_correctly(node: FaultyNode) -> None:
    messages = node.scene.messages(next(_stamps))
    for i in (LEFT_IMAGE, RIGHT_IMAGE):
        image = messages[i]
        rows = np.frombuffer(bytes(image.data), np.uint8).reshape(image.height, image.step)
        image.data = np.hstack([rows, np.full((image.height, 13), 0xEE, np.uint8)]).tobytes()
        image.step += 13
    node.publish(messages)
    assert bytes(node.disparity.wait_stamp(stamp_of(messages)).image.data) == node.good_bytes


def test_zero_sized_image(node: FaultyNode) -> None:
    node.refuses(bad(node.scene, set_info(LEFT_IMAGE, width=0, height=0, step=0, data=b"")), "zero-sized")


def test_image_larger_than_max_image_pixels(node: FaultyNode) -> None:
    fqn = f"{NS}/stereo_node"
    [ok] = node.ros.set_parameters(fqn, max_image_pixels=50_000)
    assert ok.successful
    try:
        node.refuses(
            bad(node.scene, lambda m: None), f"{NS}/left/image_raw", "347x277", "limit of 50000 pixels", good_next=False
        )
    finally:
        node.ros.set_parameters(fqn, max_image_pixels=4096 * 4096)
    node.good_frame_is_exact()


# ------------------------------------------------------------------ stamps and silent inputs


def stamp_of(messages: Messages) -> int:
    return int(messages[0].header.stamp.sec) * 10**9 + int(messages[0].header.stamp.nanosec)


def test_zero_stamps_are_refused(node: FaultyNode) -> None:
    mark = node.log_mark()
    node.refuses(node.scene.messages(0), "header.stamp is zero", "the driver must stamp every image")
    for topic in TOPICS:
        node.wait_log(mark, f"{topic}: header.stamp is zero")


def test_repeated_stamp_is_dropped_and_counted(node: FaultyNode) -> None:
    messages = node.scene.messages(next(_stamps))
    node.publish(messages)
    node.disparity.wait_stamp(stamp_of(messages))
    since = len(node.diagnostics.messages)
    line = node.refuses(messages, "is not newer than the last paired set")
    assert line.count(NS) == 1  # names the topic that repeated
    values = node.wait_diagnostics(since, "stale or repeated stamps")
    assert int(values["stale or repeated stamps"]) >= 1


def test_stamps_going_back_like_a_looping_bag_restart_pairing(node: FaultyNode) -> None:
    node.good_frame_is_exact()
    mark, since = node.log_mark(), len(node.diagnostics.messages)
    looped = node.scene.messages(1_600_000_000 * 10**9)  # far back: the bag started over
    node.publish(looped)
    assert bytes(node.disparity.wait_stamp(stamp_of(looped)).image.data) == node.good_bytes
    node.wait_log(mark, "stamps jumped back", "pairing restarted")
    key = "time jumps (pairing restarted)"
    assert int(node.wait_diagnostics(since, key)[key]) >= 1
    node.good_frame_is_exact()  # and forward again


def test_only_one_camera_publishing_is_reported_naming_the_silent_topics(node: FaultyNode) -> None:
    mark, since = node.log_mark(), len(node.diagnostics.messages)
    silent = f"{NS}/right/image_raw"

    def warned() -> bool:
        """A status at WARN whose message names the silent topic (earlier errors age out after 5 s)."""
        return any(
            a.status[0].level == DiagnosticStatus.WARN and silent in a.status[0].message
            for a in node.diagnostics.messages[since:]
        )

    deadline = time.monotonic() + 20.0
    while time.monotonic() < deadline:
        node.publish(node.scene.messages(next(_stamps)), only=(LEFT_IMAGE, LEFT_INFO))
        if warned() and any(silent in line for line in node.process.output()[mark:].splitlines()):
            break
        time.sleep(0.1)
    line = node.wait_log(mark, "no messages on", silent, f"{NS}/right/camera_info", f"while {NS}/left/camera_info")
    assert "topic remapping" in line
    assert warned()
    values = node.wait_diagnostics(since, "silent inputs", silent)
    assert f"{NS}/left/image_raw (" not in values["silent inputs"]
    node.good_frame_is_exact()
    node.wait_diagnostics(len(node.diagnostics.messages), "silent inputs", "none")


def test_an_input_losing_frames_is_reported_missing_slower_than_sent_and_as_the_bottleneck(node: FaultyNode) -> None:
    """Real traffic, real counters: every third right image never arrives (as when DDS loses a large
    image's fragments) while the other topics come at the sender's 10 Hz. Diagnostics turn WARN naming
    that topic, count its missing frames, and the bottleneck line names the inputs whose frames could
    not be paired."""
    since = len(node.diagnostics.messages)
    right, left = f"{NS}/right/image_raw", f"{NS}/left/image_raw"

    def slower() -> Any:
        for array in node.diagnostics.messages[since:]:
            status = array.status[0]
            if status.message.startswith("inputs arrive slower than sent") and right in status.message:
                return array
        return None

    deadline, found = time.monotonic() + 30.0, None
    while found is None and time.monotonic() < deadline:
        for k in range(9):
            arriving = (LEFT_IMAGE, LEFT_INFO, RIGHT_INFO) if k % 3 == 2 else (0, 1, 2, 3)
            node.publish(node.scene.messages(next(_stamps)), only=arriving)
            time.sleep(0.1)
        found = slower()
    assert found is not None, "no 'inputs arrive slower than sent' status naming the right image"
    assert found.status[0].level == DiagnosticStatus.WARN  # (earlier tests' gaps may still name others)
    values = {kv.key: kv.value for kv in found.status[0].values}
    assert int(values[f"{right} missing (recent window)"]) > 0
    bottlenecks = [
        kv.value for a in node.diagnostics.messages[since:] for kv in a.status[0].values if kv.key == "bottleneck"
    ]
    assert any(f"input {left} (lost in DDS, unmatched or stood in for)" in line for line in bottlenecks), bottlenecks
    node.good_frame_is_exact()


def test_a_flood_of_one_bad_input_is_logged_once_a_period_and_turns_diagnostics_to_warn(node: FaultyNode) -> None:
    """50 bad sets: the node says so at most once per 5 s (plus the count of the rest), skips all 50,
    and its diagnostics status is WARN naming the problem."""
    mark, since = node.log_mark(), len(node.diagnostics.messages)
    start = time.monotonic()
    flood = [bad(node.scene, set_info(RIGHT_IMAGE, encoding="uyvy")) for _ in range(50)]
    for messages in flood:
        node.publish(messages)
    node.good_frame_is_exact()  # processed after every set of the flood
    periods = math.ceil((time.monotonic() - start) / problems.PERIOD_S)
    lines = [line for line in node.process.output()[mark:].splitlines() if "'uyvy' is not supported" in line]
    assert 1 <= len(lines) <= periods, lines
    assert all(f"{NS}/right/image_raw" in line for line in lines)
    assert all("more like it since the last report" in line for line in lines[1:])
    assert not set(node.disparity.stamps()) & {stamp_of(m) for m in flood}

    def skipped_status() -> Any:
        statuses = [a.status[0] for a in node.diagnostics.messages[since:]]
        return next((s for s in statuses if "uyvy" in s.message), None)

    status = wait_until(skipped_status, "a status about the skipped frames")
    assert status.level == DiagnosticStatus.WARN and status.message.startswith("frames skipped:")


# ------------------------------------------------------------------ parameters


def test_invalid_runtime_parameters_are_refused_and_nothing_is_half_applied(node: FaultyNode) -> None:
    fqn = f"{NS}/stereo_node"
    client = node.ros._parameter_client(fqn)  # the one call the helper does not wrap
    future = client.set_parameters_atomically(
        [Parameter("disparity_range", value=32), Parameter("matcher", value="magic")]
    )
    wait_until(future.done, "atomic set")
    result = future.result().result
    assert not result.successful and "matcher 'magic' is unknown" in result.reason
    assert node.ros.get_parameters(fqn, "disparity_range", "matcher") == {"disparity_range": 64, "matcher": "sgbm"}
    [refused] = node.ros.set_parameters(fqn, max_image_pixels=0)
    assert not refused.successful and "max_image_pixels" in refused.reason
    node.good_frame_is_exact()


BAD_START = {
    "-p off-step": (["-p", "disparity_range:=40"], "disparity_range is not a valid step"),
    "-p wrong type": (["-p", "queue_size:=abc"], "expecting type 'INTEGER'"),
    "-p inconsistent": (["-p", "P1:=1000.0"], "P2 (800.0) must be greater than P1 (1000.0)"),
    "params file value": (["--params-file", "{dir}/bad_value.yaml"], "matcher 'magic' is unknown"),
    "params file syntax": (["--params-file", "{dir}/bad_syntax.yaml"], "Couldn't parse params file"),
}


def test_invalid_start_up_parameters_stop_the_node_with_the_reason(
    start_node: Callable[..., NodeProcess], tmp_path: Path
) -> None:
    (tmp_path / "bad_value.yaml").write_text("/**:\n  ros__parameters:\n    matcher: magic\n")
    (tmp_path / "bad_syntax.yaml").write_text("this: [is: not yaml\n")
    processes = {
        case: start_node("stereo_node", f"/start_{i}", [a.format(dir=tmp_path) for a in args])
        for i, (case, (args, _)) in enumerate(BAD_START.items())
    }
    for case, process in processes.items():
        code, output = process.process.wait(timeout=30), process.output()
        reason = BAD_START[case][1]
        lines = [line for line in output.splitlines() if "cannot start" in line]
        assert code == 2, f"{case}: exit code {code}\n{output}"
        assert len(lines) == 1 and reason in lines[0], f"{case}:\n{output}"
        assert "Traceback" not in output, f"{case}:\n{output}"
