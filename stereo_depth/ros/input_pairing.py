"""A node's inputs, paired: subscriptions (or raw readers), camera_info files and the synchronizer.

Subscription callbacks only stamp, count and pair messages; each complete set goes to `submit` (the
node's worker) with the receipt time of its first input. The inputs are taken on a thread of their own
(input_thread.py), not in rclpy's standard executor, which keeps the timers and services.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from functools import partial
from typing import Any

from rclpy.node import Node
from sensor_msgs.msg import CompressedImage

from stereo_depth.core.camera import CameraInfo
from stereo_depth.errors import CalibrationError, MessageError
from stereo_depth.formats.camera_info_yaml import read_camera_info_url
from stereo_depth.messages import camera_info_to_msg, same_calibration, stamp_to_ns
from stereo_depth.options import NodeOptions
from stereo_depth.ros.diagnostics import NodeDiagnostics
from stereo_depth.ros.input_thread import InputThread, NotInExecutor
from stereo_depth.ros.problems import ProblemLog
from stereo_depth.ros.qos import AdaptiveSubscription
from stereo_depth.ros.raw_inputs import raw_reader
from stereo_depth.ros.types import RCLPY_TYPES
from stereo_depth.sync import Synchronizer

# No input for this long: sets waiting only for a camera_info go out. Longer than a reliable writer takes
# to repair a lost sample (Fast DDS sends its heartbeat every 3 s), so a repaired camera_info still counts.
IDLE_FLUSH_S = 5.0
RECEIPTS_KEPT = 64  # receipt times of the first input's newest messages, looked up when their set is complete

# (stamp, messages in input order) with the monotonic receipt of its first input
Submit = Callable[[int, tuple[Any, ...], float], None]


class InputSpec:
    """What a node reads: (relative topic, message class) in synchronizer order, which of them are
    camera_info (and the input whose stamp each carries), which are images, and which camera_info a
    file may replace (and the option naming it)."""

    def __init__(
        self,
        inputs: Sequence[tuple[str, Any]],
        calibrations: Sequence[tuple[int, int]],
        image_inputs: Sequence[int],
        camera_info_files: Sequence[tuple[int, str]],
    ) -> None:
        self.inputs, self.calibrations = inputs, dict(calibrations)
        self.image_inputs, self.camera_info_files = image_inputs, camera_info_files


class InputTopics:
    """Where each input is read from, fixed at configure: its resolved topic, or the camera_info file
    that replaces it ({camera_info input: (url, image input, calibration)})."""

    def __init__(self, node: Node, spec: InputSpec, options: NodeOptions) -> None:
        inputs = input_specs(spec.inputs, spec.image_inputs, options)
        self.info_files = camera_info_files(spec.camera_info_files, spec.calibrations, options)
        self.names = [
            self.info_files[index][0] if index in self.info_files else node.resolve_topic_name(topic)
            for index, (topic, _) in enumerate(inputs)
        ]


class InputPairing:
    """The node's input side while it is active: subscriptions on the input thread (or in the executor with
    executor:=events), the synchronizer, and complete sets handed to `submit`. Half-paired sets are
    dropped at `close`."""

    def __init__(
        self,
        node: Node,
        spec: InputSpec,
        topics: InputTopics,
        options: NodeOptions,
        diagnostics: NodeDiagnostics,
        problems: ProblemLog,
        submit: Submit,
        report_bug: Callable[[Exception], None],
    ) -> None:
        self._node, self._spec = node, spec
        self.topics, self.info_files = topics.names, topics.info_files
        self.diagnostics, self.problems = diagnostics, problems
        self._submit: Submit | None = submit
        self._lock = threading.Lock()
        self._sync = self._new_sync(options)
        self._last_input_s = 0.0  # monotonic time of the newest input message; 0 once flushed
        self._receipts: dict[int, float] = {}  # stamp -> monotonic receipt of the first input's message
        inputs = input_specs(spec.inputs, spec.image_inputs, options)
        threaded = options.executor != "events"
        group = NotInExecutor() if threaded else None
        readers = [raw_reader(msg_type) for _, msg_type in inputs]  # None: taken as rclpy's message
        self.subscriptions = [
            AdaptiveSubscription(
                node,
                msg_type,
                topic,
                self._input_callback(index, options.executor, readers[index]),
                policy=options.reliability,
                depth=options.queue_size,
                on_lost=partial(self.diagnostics.input_lost, self.topics[index]),
                callback_group=group,
                on_replaced=self._inputs_replaced,
                raw=readers[index] is not None,
            )
            for index, (topic, msg_type) in enumerate(inputs)
            if index not in self.info_files
        ]
        self._input_thread: InputThread | None = None  # None: the executor takes the inputs (executor:=events)
        if threaded:
            self._input_thread = InputThread(node, lambda: [i.subscription for i in self.subscriptions], report_bug)

    def close(self) -> None:
        """No more inputs; half-paired sets are dropped."""
        if self._input_thread is not None:
            self._input_thread.stop()
            self._input_thread = None
        for subscription in self.subscriptions:
            subscription.destroy()
        self.subscriptions, self._submit = [], None
        with self._lock:
            self._sync.reset()

    def options_changed(self, old: NodeOptions, new: NodeOptions) -> None:
        if any(getattr(old, n) != getattr(new, n) for n in ("queue_size", "approximate_sync", "tolerance_ns")):
            with self._lock:
                self._sync.reset()
                self._sync = self._new_sync(new)
        if (old.reliability, old.queue_size) != (new.reliability, new.queue_size):
            for subscription in self.subscriptions:
                subscription.configure(new.reliability, new.queue_size)

    def flush_when_idle(self) -> bool:
        """The stream paused: a set that waits only for its camera_info goes out with the last one, as at
        the end of a bag, instead of waiting for the next frame. True when it flushed now."""
        if self._last_input_s and time.monotonic() - self._last_input_s > IDLE_FLUSH_S:
            self._last_input_s = 0.0
            self._pair(Synchronizer.flush, "", 0)
            return True
        return False

    def _new_sync(self, options: NodeOptions) -> Synchronizer:
        return Synchronizer(
            len(self._spec.inputs),
            queue_size=options.queue_size,
            approximate=options.approximate_sync,
            tolerance_ns=options.tolerance_ns,
            calibrations=self._spec.calibrations,
            same_calibration=same_calibration,
        )

    def _input_callback(self, index: int, executor: str, read: Callable[[bytes], Any] | None) -> Callable[..., None]:
        """Input `index`'s subscription callback: rclpy's standard executor passes a two-argument one the DDS
        sample info too; the EventsExecutor calls every callback with the message alone. With `read`, the
        subscription is raw: `read` makes the message of its bytes (raw_inputs)."""
        receive = partial(self._on_message, index) if read is None else partial(self._on_raw, index, read)
        if executor == "events":
            return lambda msg: receive(msg, None)
        return receive

    def _on_raw(self, index: int, read: Callable[[bytes], Any], raw: bytes, sample: dict[str, int] | None) -> None:
        """Input `index`'s message as its CDR bytes."""
        try:
            msg = read(raw)
        except MessageError as exc:
            topic = self.topics[index]
            self.problems.skipped(f"{topic}: {exc}", ("unreadable", topic))
            return
        self._on_message(index, msg, sample)

    def _inputs_replaced(self) -> None:
        if self._input_thread is not None:
            self._input_thread.changed()

    def _on_message(self, index: int, msg: Any, sample: dict[str, int] | None) -> None:
        """A message of input `index`, with its DDS sample info (None for a calibration file's)."""
        stamp = stamp_to_ns(msg.header.stamp)
        topic = self.topics[index]
        sent, received = (sample or {}).get("source_timestamp"), (sample or {}).get("received_timestamp")
        if sent and received:  # None or 0: a calibration file's, or an RMW that does not stamp samples
            self.diagnostics.input_in_dds(topic, (received - sent) / 1e6)
        if stamp == 0:
            self.problems.skipped(
                f"{topic}: header.stamp is zero, message skipped; the driver must stamp every image and "
                "camera_info with its capture time, or left and right cannot be paired",
                ("zero stamp", topic),
            )
            return
        self.diagnostics.input_received(topic, stamp)
        self._last_input_s = time.monotonic()
        if index == 0:  # a set carries its first input's stamp
            with self._lock:
                self._receipts.setdefault(stamp, self._last_input_s)
                if len(self._receipts) > RECEIPTS_KEPT:
                    del self._receipts[next(iter(self._receipts))]
        self._pair(lambda sync: sync.add(index, stamp, msg), topic, stamp)
        for info_index, (_, image_index, info) in self.info_files.items():
            if image_index == index:  # the file's calibration, stamped as this image, takes the topic's place
                self._on_message(info_index, camera_info_to_msg(RCLPY_TYPES, msg.header, info), None)

    def _pair(self, step: Callable[[Synchronizer], list[tuple[int, tuple[Any, ...]]]], topic: str, stamp: int) -> None:
        """One synchronizer step; its counters go to diagnostics per topic, the sets to `submit`."""
        with self._lock:
            before = self._sync.counters.copy()
            sets = step(self._sync)
            change = self._sync.counters.since(before)
            received = [self._receipts.pop(stamp_ns, time.monotonic()) for stamp_ns, _ in sets]
        self.diagnostics.sync_changed(change, self.topics)
        if change.stale:
            self.problems.skipped(
                f"{topic}: stamp {stamp / 1e9:.6f} s is not newer than the last paired set (repeated, or "
                "back by less than 1 s), message dropped; each frame needs a new, increasing stamp",
                ("stale stamp", topic),
            )
        if change.time_jumps:
            self.problems.info(
                f"{topic}: stamps jumped back to {stamp / 1e9:.3f} s (a looping bag or a restarted driver); "
                "pairing restarted from there",
                ("time jump", topic),
            )
        submit = self._submit
        for (stamp_ns, messages), received_s in zip(sets, received, strict=True):
            if submit is not None:  # None: deactivated since this message arrived
                submit(stamp_ns, messages, received_s)


def input_specs(
    inputs: Sequence[tuple[str, Any]], image_inputs: Sequence[int], options: NodeOptions
) -> list[tuple[str, Any]]:
    """The node's inputs with image_transport applied: `<topic>/compressed` as CompressedImage, the name
    and meaning of stereo_image_proc's parameter (decoded on the worker, in frames.decode_image)."""
    if options.image_transport != "compressed":
        return list(inputs)
    return [
        (f"{topic}/compressed", CompressedImage) if i in image_inputs else (topic, kind)
        for i, (topic, kind) in enumerate(inputs)
    ]


def camera_info_files(
    files: Sequence[tuple[int, str]], calibrations: dict[int, int], options: NodeOptions
) -> dict[int, tuple[str, int, CameraInfo]]:
    """{camera_info input: (url, image input, calibration)} for each *_camera_info_url that is set; a
    file that cannot be read stops the node at start-up with the reason (as a driver would)."""
    out = {}
    for index, option in files:
        url = str(getattr(options, option))
        if url:
            try:
                out[index] = (url, calibrations[index], read_camera_info_url(url))
            except CalibrationError as exc:
                msg = f"{option}: {exc}"
                raise CalibrationError(msg) from exc
    return out
