"""What the nodes share: inputs -> synchronizer -> bounded worker -> outputs, plus `main()`.

Subscription callbacks only stamp, count and pair messages; the work runs on a worker thread that
takes complete sets oldest first from a short queue (latest_worker.py: at most `max_waiting_frames`,
fewer as the node falls behind, newest only under sustained overload; `max_latency_ms` drops a set
that could not be out in time). Dropped sets are counted, so latency stays bounded instead of a
backlog growing; the waiting places absorb a busy machine's scheduling hiccups, which a single slot
turns into lost frames even at a rate the node easily sustains. A node may process several sets at
once (`frames_at_once`); its outputs still leave in input order. Diagnostics report each output's age
at publish, from the receipt of the set's first input.
The inputs are taken on a thread of their own (input_thread.py), not in rclpy's standard executor, which
keeps the timers and services; OpenCV releases the GIL, so inputs keep arriving while a frame is processed.
"""

from __future__ import annotations

import itertools
import sys
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from functools import partial
from typing import Any, TypeVar

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import Executor, ExternalShutdownException
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import QoSProfile
from rclpy.qos_overriding_options import QoSOverridingOptions
from rclpy.signals import SignalHandlerOptions
from rclpy.timer import Timer
from sensor_msgs.msg import CompressedImage

from stereo_depth.core.camera import CameraInfo, StereoCamera
from stereo_depth.core.params import StereoParams
from stereo_depth.core.pipeline import StereoPipeline, StereoResult
from stereo_depth.core.temporal import compile_kernels
from stereo_depth.core.threads import use_threads
from stereo_depth.errors import CalibrationError, MessageError, StereoDepthError
from stereo_depth.formats.camera_info_yaml import read_camera_info_url
from stereo_depth.frames import InputNames, StereoFrame, camera_fixes, decode_frame, decode_image, match_frame, named
from stereo_depth.messages import camera_info_to_msg, make_header, same_calibration, stamp_to_ns
from stereo_depth.options import NodeOptions, Settings
from stereo_depth.ros import signals
from stereo_depth.ros.diagnostics import NodeDiagnostics
from stereo_depth.ros.input_thread import InputThread, NotInExecutor
from stereo_depth.ros.latest_worker import LatestWorker
from stereo_depth.ros.parameters import NodeParameters
from stereo_depth.ros.problems import ProblemLog, error_key
from stereo_depth.ros.qos import (
    AdaptiveSubscription,
    SubscriberWatch,
    output_qos,
    override_errors,
    unused_overrides_line,
)
from stereo_depth.ros.raw_inputs import raw_reader
from stereo_depth.ros.transport import use_large_message_profile
from stereo_depth.ros.types import RCLPY_TYPES
from stereo_depth.sync import StereoSet, Synchronizer

T = TypeVar("T")
# An input's publisher or an output's subscriber that came or went (AdaptiveSubscription, SubscriberWatch) is
# looked at within this; every one of them at the second.
QOS_RECHECK_S = 0.25
QOS_FULL_RECHECK_S = 2.0
# No input for this long: sets waiting only for a camera_info go out. Longer than a reliable writer takes
# to repair a lost sample (Fast DDS sends its heartbeat every 3 s), so a repaired camera_info still counts.
IDLE_FLUSH_S = 5.0
SIGNAL_POLL_S = 0.25  # the longest a SIGINT / SIGTERM waits for the spin to return to Python
RECEIPTS_KEPT = 64  # receipt times of the first input's newest messages, looked up when their set is complete
# How long a thread running Python may keep the GIL while another waits for it (Python's default: 5 ms). The
# census core returns to Python between its kernels dozens of times a frame, and each time waits for the GIL
# while the executor or the cloud stage runs Python: at 5 ms that took its match from 50 to 180 ms beside
# one busy Python thread, at 0.5 ms to 100 ms, what sharing a core costs (docs/design/decisions.md).
GIL_SWITCH_S = 0.0005


class StereoIONode(Node):
    """Base of the nodes. A subclass names its inputs and options and implements `process`.

    What a node holds is built in the steps of a ROS lifecycle, which a plain node runs at start and a
    managed one (stereo_lifecycle_node) on its transitions: parameters (__init__), publishers and the
    matcher (`configure_io`), workers and subscriptions (`activate_io`), and back."""

    INPUTS: Sequence[tuple[str, Any]] = ()  # (relative topic, message class), in synchronizer order
    CALIBRATIONS: Sequence[tuple[int, int]] = ()  # (camera_info input, the input whose stamp it carries)
    IMAGE_INPUTS: Sequence[int] = ()  # inputs that image_transport:=compressed reads from <topic>/compressed
    # (camera_info input, the option naming a file that replaces it; its image input is in CALIBRATIONS)
    CAMERA_INFO_FILES: Sequence[tuple[int, str]] = ()
    OUTPUTS: Sequence[tuple[str, Any]] = ()  # (relative topic, message class) this node publishes
    OUTPUT_SWITCHES: Mapping[str, str] = {}  # output topic -> the publish_* parameter that switches it
    STATUS_OUTPUT: tuple[str, Any] = ("diagnostics", DiagnosticArray)  # every node's, about once a second
    OPTIONS: Sequence[str] = ()  # NodeOptions fields this node declares
    WITH_STEREO = False  # declares the processing parameters (StereoParams) and owns a pipeline
    MAX_FRAMES_AT_ONCE = 1  # worker threads; see `frames_at_once`

    def __init__(self, name: str, *, managed: bool = False, **kwargs: Any) -> None:
        """Declares the parameters. A plain node then configures and activates itself; a `managed` one
        (lifecycle) waits for its transitions, having created nothing else."""
        super().__init__(name, **kwargs)
        self.parameters = NodeParameters(
            self, self.OPTIONS, with_stereo=self.WITH_STEREO, on_change=self._settings_changed
        )
        self._options = self.parameters.settings.options
        self.topics: list[str] = []
        self._new_diagnostics()
        self.pipeline: StereoPipeline | None = None
        self._info_files: dict[int, tuple[str, int, CameraInfo]] = {}
        self._outputs: list[Publisher] = []
        self._watches: list[SubscriberWatch] = []  # one per output: its incompatible-QoS warnings
        self._inputs: list[AdaptiveSubscription] = []
        self._input_thread: InputThread | None = None  # None: the executor takes the inputs (executor:=events)
        self._io_timers: list[Timer] = []
        self._worker: LatestWorker | None = None
        self._sync_lock = threading.Lock()
        self._sync = self._new_sync(self._options)
        self._last_input_s = 0.0  # monotonic time of the newest input message; 0 once flushed
        self._receipts: dict[int, float] = {}  # stamp -> monotonic receipt of the first input's message
        self._sequence = itertools.count(1)  # input order of the matched sets
        self._order_lock = threading.Lock()
        self._published = 0  # sequence number of the newest set whose outputs went out
        self._frame = threading.local()  # the sequence number of the set this worker thread processes
        self._overrides_checked = False
        if not managed:
            try:
                self.configure_io()
                self.activate_io()
            except BaseException:
                # A bad setting, or a signal's SystemExit during start-up: what started so far (worker threads,
                # DDS entities) ends here, not in the interpreter's and Fast DDS's teardown at process exit.
                self.destroy_node()
                raise

    # ------------------------------------------------------------ life cycle (a plain node runs all at start)

    def configure_io(self) -> None:
        """Calibration files, the pipeline (matcher) and the publishers; nothing is received yet."""
        settings = self.parameters.settings
        inputs = input_specs(self.INPUTS, self.IMAGE_INPUTS, settings.options)
        self._info_files = camera_info_files(self.CAMERA_INFO_FILES, dict(self.CALIBRATIONS), settings.options)
        self.topics = [
            self._info_files[index][0] if index in self._info_files else self.resolve_topic_name(topic)
            for index, (topic, _) in enumerate(inputs)
        ]
        if settings.stereo is not None:
            self.pipeline = StereoPipeline(settings.stereo)
        fixes = camera_fixes(settings.output)
        if fixes is not None:
            self.get_logger().info(f"inputs corrected: {fixes}")
        self.open_outputs()
        status_topic, status_type = self.STATUS_OUTPUT
        self._diagnostics_pub = self.output(status_type, status_topic, depth=10)

    def activate_io(self) -> None:
        """Workers, then the input subscriptions and the timers: frames flow from here on."""
        settings = self.parameters.settings
        self._new_diagnostics()
        self.start_workers()
        inputs = input_specs(self.INPUTS, self.IMAGE_INPUTS, settings.options)
        threaded = settings.options.executor != "events"
        group = NotInExecutor() if threaded else None
        readers = [raw_reader(msg_type) for _, msg_type in inputs]  # None: taken as rclpy's message
        self._inputs = [
            AdaptiveSubscription(
                self,
                msg_type,
                topic,
                self._input_callback(index, settings.options.executor, readers[index]),
                policy=settings.options.reliability,
                depth=settings.options.queue_size,
                on_lost=partial(self.diagnostics.input_lost, self.topics[index]),
                callback_group=group,
                on_replaced=self._inputs_replaced,
                raw=readers[index] is not None,
            )
            for index, (topic, msg_type) in enumerate(inputs)
            if index not in self._info_files
        ]
        if threaded:
            self._input_thread = InputThread(self, lambda: [i.subscription for i in self._inputs], self.report_bug)
        self._io_timers = [
            self.create_timer(1.0, self._publish_diagnostics),
            self.create_timer(QOS_RECHECK_S, partial(self._recheck_qos, False)),
            self.create_timer(1.0, self._flush_when_idle),
            self.create_timer(QOS_FULL_RECHECK_S, partial(self._recheck_qos, True)),
        ]
        self._warn_unused_overrides()
        self.get_logger().info(f"ready: inputs {', '.join(self.topics)}")

    def deactivate_io(self) -> None:
        """Unsubscribe, let the running frame finish, end the workers; half-paired sets are dropped."""
        if self._input_thread is not None:
            self._input_thread.stop()
            self._input_thread = None
        for subscription in self._inputs:
            subscription.destroy()
        for timer in self._io_timers:
            self.destroy_timer(timer)
        self._inputs, self._io_timers = [], []
        self.stop_workers()
        with self._sync_lock:
            self._sync.reset()

    def cleanup_io(self) -> None:
        """Back to the state after __init__: publishers, pipeline and calibration files released."""
        self.deactivate_io()
        for publisher in self._outputs:
            self.destroy_output(publisher)
        self._outputs, self._watches = [], []
        self.pipeline = None
        self._info_files = {}

    def _new_diagnostics(self) -> None:
        """Fresh counters at each activation: a re-activated node reports nothing from before its pause."""
        self.diagnostics = NodeDiagnostics(self.get_fully_qualified_name(), self.topics)
        self.problems = ProblemLog(self.get_logger(), self.diagnostics)

    def _warn_unused_overrides(self) -> None:
        """Once per process, when every endpoint exists: qos_overrides that match none of them."""
        if self._overrides_checked:
            return
        self._overrides_checked = True
        line = unused_overrides_line(self)
        if line is not None:
            self.get_logger().warning(line)

    # ------------------------------------------------------------ to implement / use in subclasses

    def process(self, stamp_ns: int, messages: tuple[Any, ...], settings: Settings) -> dict[str, float] | None:
        """Turn one matched set (its stamp, its messages in INPUTS order) into outputs; return per-stage
        times (ms) for diagnostics, or None when the rest of the frame was handed to another thread,
        which calls `finish_frame` when done."""
        raise NotImplementedError

    def frames_at_once(self, settings: Settings) -> int:
        """How many sets may be processed at once (at most MAX_FRAMES_AT_ONCE); 1 unless overridden."""
        return 1

    def open_outputs(self) -> None:
        """At configure: create the node's publishers with `output` (and any per-output state)."""

    def start_workers(self) -> None:
        """At activate: the worker that processes matched sets; a node with more threads extends this."""
        settings = self.parameters.settings
        self._worker = LatestWorker(
            self._run_frame,
            self.diagnostics.frame_dropped,
            settings.options.max_waiting_frames,
            threads=self.MAX_FRAMES_AT_ONCE,
        )
        self._worker.parallel = self.frames_at_once(settings)
        self._worker.budget_s = settings.options.max_latency_ms / 1000.0
        with signals.interruptible():  # numba's load or first compile: Ctrl-C need not wait for it
            if settings.output.temporal_filter:
                compile_kernels()  # the temporal filter's, now rather than on the first frame
            if settings.stereo is not None and settings.stereo.matcher == "census_sgm":
                self._load_census_core()
            if self.pipeline is not None:
                self.pipeline.load_kernels()  # our BM's, for its disparity count

    def _load_census_core(self) -> None:
        """The census core's machine code now, before any input is subscribed, rather than on the first
        frame: numba loads it from its cache in about a second, or compiles it first (one to two minutes) on the
        first start after installing, while frames would wait. A matcher switched to at run time still
        loads on its first frame."""
        from stereo_depth.core.census_sgm import compile_kernels as load_census_core  # numba: census nodes only

        self.get_logger().info(
            "census_sgm core: loading its machine code (compiled on the first start after installing, "
            "one to two minutes; `stereo-depth compile` does that ahead)"
        )
        start = time.perf_counter()
        cache = load_census_core()
        self.get_logger().info(f"census_sgm core ready in {time.perf_counter() - start:.1f} s (numba cache: {cache})")

    @contextmanager
    def outputs_in_order(self) -> Iterator[bool]:
        """Hold while a frame publishes. Yields False, and counts the frame as dropped, when a newer
        set processed beside this one has published already: subscribers never see stamps go back."""
        with self._order_lock:
            sequence = self._frame.sequence
            if sequence < self._published:
                self.diagnostics.add_dropped(1)
                yield False
                return
            self._published = sequence
            yield True

    def output(self, msg_type: Any, topic: str, depth: int | None = None) -> Publisher:
        """A publisher with our output QoS (or history `depth`), which the user's qos_overrides amend."""
        qos = output_qos() if depth is None else depth
        with override_errors():
            publisher = self.create_output(
                msg_type,
                topic,
                qos,
                qos_overriding_options=QoSOverridingOptions.with_default_policies(),
                event_callbacks=PublisherEventCallbacks(use_default_callbacks=False),  # SubscriberWatch warns
            )
        self._outputs.append(publisher)
        self._watches.append(SubscriberWatch(self, publisher))
        return publisher

    def declared_output(self, topic: str) -> Publisher:
        """The publisher of one of OUTPUTS (the topics docs/parameters.md lists for this node)."""
        return self.output(dict(self.OUTPUTS)[topic], topic)

    def create_output(self, msg_type: Any, topic: str, qos: QoSProfile | int, **options: Any) -> Publisher:
        """A plain publisher (`options`: create_publisher's); the lifecycle node makes it a lifecycle publisher."""
        return self.create_publisher(msg_type, topic, qos, **options)

    def destroy_output(self, publisher: Publisher) -> None:
        self.destroy_publisher(publisher)

    @staticmethod
    def wanted(publisher: Publisher, enabled: bool) -> bool:
        """Worth computing and serializing only when switched on and someone listens."""
        return enabled and publisher.get_subscription_count() > 0

    def read_input(self, index: int, convert: Callable[[Any], T], msg: Any) -> T:
        """`convert(msg)`, with the input's topic named in any error it raises."""
        return named(self.topics[index], convert, msg)

    def read_image(self, index: int, msg: Any, settings: Settings) -> Any:
        return named(self.topics[index], decode_image, msg, settings.output.max_image_pixels)

    def read_frame(
        self, inputs: StereoSet, settings: Settings, *, rectified: bool, names: InputNames | None = None
    ) -> StereoFrame:
        """`decode_frame`, errors naming the topics (`names`: where INPUTS are not a stereo set's four)."""
        assert self.pipeline is not None
        names = names or InputNames(*self.topics)
        loaded = self.pipeline.calibrations_built
        frame = decode_frame(inputs, self.pipeline, settings.output, rectified=rectified, names=names)
        self._note_calibration(loaded, frame.camera, (names.left_info, names.right_info))
        return frame

    def match(self, frame: StereoFrame) -> StereoResult:
        """`match_frame`, with both image topics named in any error it raises."""
        assert self.pipeline is not None
        return match_frame(self.pipeline, frame, InputNames(*self.topics))

    def _note_calibration(self, loaded: int, camera: StereoCamera, names: tuple[str, str]) -> None:
        """Diagnostics and one log line when the pipeline built a new calibration for this frame."""
        assert self.pipeline is not None
        if self.pipeline.calibrations_built == loaded:
            return
        self.diagnostics.calibrations_loaded(self.pipeline.calibrations_built)
        self.problems.info(
            f"calibration {'changed' if loaded else 'received'} (left = {names[0]}, right = {names[1]}): "
            f"{camera.width}x{camera.height}, fx {camera.fx:.1f} px, baseline {camera.baseline:.4f} m; "
            "rectification maps rebuilt",
            key=("calibration", str(hash(camera.key()))),
        )

    def published(self, name: str) -> None:
        """Diagnostics: the age of this thread's frame's `name` output as it went out, from the receipt
        of the frame's first input (what a subscriber of both sees as the node's delay)."""
        self.diagnostics.output_age(name, time.monotonic() - self._frame.received_s)

    def finish_frame(self, stamp_ns: int, stage_ms: dict[str, float]) -> None:
        """A frame's outputs are all published: its stage times and latency go to diagnostics."""
        latency_s = (self.get_clock().now().nanoseconds - stamp_ns) / 1e9
        self.diagnostics.frame_done(stage_ms, latency_s)

    def guarded(self, work: Callable[[], None]) -> None:
        """Run one frame's work on a worker thread: bad input is logged (throttled) and the frame
        skipped; anything else is a bug, reported as such, and the node keeps serving."""
        try:
            work()
        except StereoDepthError as exc:
            self.problems.skipped(str(exc), error_key(exc))
        except Exception as exc:
            if self.context.ok():  # else shutting down: publishers are gone
                self.report_bug(exc)

    def report_bug(self, exc: Exception) -> None:
        """An exception no input explains (a worker's, or an input callback's on the input thread): diagnostics
        and a throttled log line; the node keeps serving."""
        self.diagnostics.error(f"internal error: {exc!r}")
        self.get_logger().error(f"internal error, please report: {exc!r}", throttle_duration_sec=5.0)

    # ------------------------------------------------------------ internals

    def _new_sync(self, options: NodeOptions) -> Synchronizer:
        return Synchronizer(
            len(self.INPUTS),
            queue_size=options.queue_size,
            approximate=options.approximate_sync,
            tolerance_ns=options.tolerance_ns,
            calibrations=dict(self.CALIBRATIONS),
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
            with self._sync_lock:
                self._receipts.setdefault(stamp, self._last_input_s)
                if len(self._receipts) > RECEIPTS_KEPT:
                    del self._receipts[next(iter(self._receipts))]
        self._pair(lambda sync: sync.add(index, stamp, msg), topic, stamp)
        for info_index, (_, image_index, info) in self._info_files.items():
            if image_index == index:  # the file's calibration, stamped as this image, takes the topic's place
                self._on_message(info_index, camera_info_to_msg(RCLPY_TYPES, msg.header, info), None)

    def _pair(self, step: Callable[[Synchronizer], list[tuple[int, tuple[Any, ...]]]], topic: str, stamp: int) -> None:
        """One synchronizer step; its counters go to diagnostics per topic, the sets to the worker."""
        with self._sync_lock:
            before = self._sync.counters.copy()
            sets = step(self._sync)
            change = self._sync.counters.since(before)
            received = [self._receipts.pop(stamp_ns, time.monotonic()) for stamp_ns, _ in sets]
        self.diagnostics.sync_changed(change)
        if change.stale:
            self._stale_stamp(topic, stamp)
        if change.time_jumps:
            self._time_jump(topic, stamp)
        worker = self._worker
        for (stamp_ns, messages), received_s in zip(sets, received, strict=True):
            if worker is not None:  # None: deactivated since this message arrived
                worker.submit((next(self._sequence), stamp_ns, received_s, messages), received_s)

    def _flush_when_idle(self) -> None:
        """The stream paused: a set that waits only for its camera_info goes out with the last one, as at
        the end of a bag, instead of waiting for the next frame."""
        if self._last_input_s and time.monotonic() - self._last_input_s > IDLE_FLUSH_S:
            self._last_input_s = 0.0
            self._pair(Synchronizer.flush, "", 0)

    def _stale_stamp(self, topic: str, stamp_ns: int) -> None:
        self.problems.skipped(
            f"{topic}: stamp {stamp_ns / 1e9:.6f} s is not newer than the last paired set (repeated, or "
            "back by less than 1 s), message dropped; each frame needs a new, increasing stamp",
            ("stale stamp", topic),
        )

    def _time_jump(self, topic: str, stamp_ns: int) -> None:
        self.problems.info(
            f"{topic}: stamps jumped back to {stamp_ns / 1e9:.3f} s (a looping bag or a restarted driver); "
            "pairing restarted from there",
            ("time jump", topic),
        )

    def _settings_changed(self, settings: Settings) -> None:
        """Runs after a successful parameter change; the worker picks the new set up on its next frame."""
        old, new = self._options, settings.options
        self._options = new
        if self._worker is not None:
            self._worker.capacity = new.max_waiting_frames
            self._worker.parallel = self.frames_at_once(settings)
            self._worker.budget_s = new.max_latency_ms / 1000.0
        if any(getattr(old, n) != getattr(new, n) for n in ("queue_size", "approximate_sync", "tolerance_ns")):
            with self._sync_lock:
                self._sync.reset()
                self._sync = self._new_sync(new)
        if (old.reliability, old.queue_size) != (new.reliability, new.queue_size):
            for subscription in self._inputs:
                subscription.configure(new.reliability, new.queue_size)

    def _recheck_qos(self, everything: bool) -> None:
        """Each input's reliability and publishers' types, each output's subscribers' QoS: looked at when
        their count moved, or `everything`."""
        endpoints: list[AdaptiveSubscription | SubscriberWatch] = [*self._inputs, *self._watches]
        for endpoint in endpoints:
            endpoint.check(everything=everything)

    def _run_frame(self, job: tuple[int, int, float, tuple[Any, ...]]) -> None:
        self._frame.sequence, stamp_ns, self._frame.received_s, messages = job

        def work() -> None:
            settings = self.parameters.settings
            if self.pipeline is not None and settings.stereo is not None:
                self._use_params(self.pipeline, settings.stereo)
                use_threads(settings.options.cpu_threads, self.frames_at_once(settings))
            stage_ms = self.process(stamp_ns, messages, settings)
            if stage_ms is not None:
                self.finish_frame(stamp_ns, stage_ms)

        self.guarded(work)

    @staticmethod
    def _use_params(pipeline: StereoPipeline, params: StereoParams) -> None:
        """Parameter changes reach the pipeline here, on the worker thread, between two frames."""
        if pipeline.params is not params:
            pipeline.set_params(params)

    def _publish_diagnostics(self) -> None:
        silence = self.diagnostics.silent_inputs()
        if silence:
            self.problems.warn(silence, ("silent inputs",))
        header = make_header(RCLPY_TYPES, self.get_clock().now().nanoseconds, "")
        self._diagnostics_pub.publish(self.diagnostics.report(header))

    def stop_workers(self) -> None:
        """Let the running frame finish and start nothing new; a node with more threads extends this,
        so that none of them publishes while the node is being destroyed. Ends what a start-up cut short
        started, too."""
        if self._worker is not None:
            self._worker.stop()
            self._worker = None

    def destroy_node(self) -> None:
        self.deactivate_io()
        super().destroy_node()


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


def timed(stages: dict[str, float], name: str, start: float) -> None:
    stages[name] = (time.perf_counter() - start) * 1000.0


def run_node(factory: Callable[[], StereoIONode], args: list[str] | None = None) -> int:
    """rclpy Jazzy's main(). SIGINT / SIGTERM end the spin loop below, or start-up at its next step
    (ros/signals.py), and the `finally` below stops the worker and destroys the node before the process
    ends with 0.
    A node that cannot start (bad --ros-args, --params-file or parameter value) says why in one
    line and exits with 2, rather than run with part of its configuration."""
    signals.install()
    if signals.SIGNALLED.is_set():  # during the imports
        return 0
    sys.setswitchinterval(GIL_SWITCH_S)
    profile = use_large_message_profile()
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except RuntimeError as exc:  # rcl's error (unreadable --params-file, malformed --ros-args) is one
        rclpy.logging.get_logger("stereo_depth").error(f"cannot start: {_rcl_reason(exc)}")
        return 2
    node: StereoIONode | None = None
    code = 0
    try:
        node = factory()
        if profile is not None:
            node.get_logger().info(
                f"Fast DDS: large-message profile {profile} for this process (no profile was exported); see "
                "docs/dds.md#large-messages"
            )
        executor = new_executor(node)
        executor.add_node(node)
        signals.SPINNING.set()
        try:
            # The signal handler runs between two bytecodes of this thread: the wait must return now and then,
            # also in a lifecycle state without timers of the node's own (unconfigured, inactive, finalized).
            while not signals.SIGNALLED.is_set() and executor.context.ok():
                executor.spin_once(timeout_sec=SIGNAL_POLL_S)
        finally:
            executor.remove_node(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (StereoDepthError, InvalidParameterValueException, InvalidParameterTypeException) as exc:
        rclpy.logging.get_logger("stereo_depth").error(f"cannot start: {exc}")
        code = 2
    except Exception:
        # A signal that cut numba's start-up short (signals.interruptible): its SystemExit can come out of
        # numba's imports or C calls as another exception. Still the signal's exit.
        if not signals.SIGNALLED.is_set():
            raise
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code


def new_executor(node: StereoIONode) -> Executor:
    """The executor the node's `executor` parameter names: rclpy's standard one, or its EventsExecutor, which
    waits and dispatches in C++ instead of rebuilding a wait set of every entity in Python on each wake."""
    if node.parameters.settings.options.executor == "events":
        try:
            from rclpy.experimental.events_executor import EventsExecutor
        except ImportError:  # an rclpy older than the EventsExecutor (the Jazzy wheels have it)
            node.get_logger().warning("executor:=events: this rclpy has no EventsExecutor; running the standard one")
        else:
            node.get_logger().info("executor: rclpy's EventsExecutor (executor:=events)")
            return EventsExecutor()
    return rclpy.get_global_executor()


def _rcl_reason(exc: Exception) -> str:
    """rcl's message on one line, without the C source locations it appends (", at file.c:123")."""
    return " ".join(str(exc).split(", at /")[0].split())
