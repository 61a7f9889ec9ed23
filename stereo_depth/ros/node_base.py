"""What the nodes share: lifecycle steps, outputs, and the bounded worker that processes matched sets.

The paired sets (input_pairing.py) go to a worker thread that takes them oldest first from a short queue
(latest_worker.py: at most `max_waiting_frames`, fewer as the node falls behind, newest only under
sustained overload; `max_latency_ms` drops a set that could not be out in time). Dropped sets are counted,
so latency stays bounded instead of a backlog growing; the waiting places absorb a busy machine's
scheduling hiccups, which a single slot turns into lost frames even at a rate the node easily sustains. A
node may process several sets at once (`frames_at_once`); its outputs still leave in input order.
Diagnostics report each output's age at publish, from the receipt of the set's first input.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Mapping, Sequence
from functools import partial
from typing import Any, NamedTuple

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import QoSProfile
from rclpy.qos_overriding_options import QoSOverridingOptions
from rclpy.timer import Timer

from stereo_depth.errors import StereoDepthError
from stereo_depth.frames import camera_fixes
from stereo_depth.messages import make_header
from stereo_depth.options import Settings
from stereo_depth.ros.diagnostics import NodeDiagnostics
from stereo_depth.ros.input_pairing import InputPairing, InputSpec, InputTopics
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
from stereo_depth.ros.types import RCLPY_TYPES

# An input's publisher or an output's subscriber that came or went (AdaptiveSubscription, SubscriberWatch) is
# looked at within this; every one of them at the second.
QOS_RECHECK_S = 0.25
QOS_FULL_RECHECK_S = 2.0


class FrameJob(NamedTuple):
    """One matched set as the worker hands it on: its place in input order, stamp, the receipt of its
    first input (monotonic s: its outputs' age and latency budget count from it) and its messages."""

    sequence: int
    stamp_ns: int
    received_s: float
    messages: tuple[Any, ...]


class StereoIONode(Node):
    """Base of the nodes. A subclass names its inputs and options and implements `process`.

    What a node holds is built in the steps of a ROS lifecycle, which a plain node runs at start and a
    managed one (stereo_lifecycle_node) on its transitions: parameters (__init__), publishers
    (`configure_io`), workers and subscriptions (`activate_io`), and back."""

    INPUTS: Sequence[tuple[str, Any]] = ()  # (relative topic, message class), in synchronizer order
    CALIBRATIONS: Sequence[tuple[int, int]] = ()  # (camera_info input, the input whose stamp it carries)
    IMAGE_INPUTS: Sequence[int] = ()  # inputs that image_transport:=compressed reads from <topic>/compressed
    # (camera_info input, the option naming a file that replaces it; its image input is in CALIBRATIONS)
    CAMERA_INFO_FILES: Sequence[tuple[int, str]] = ()
    OUTPUTS: Sequence[tuple[str, Any]] = ()  # (relative topic, message class) this node publishes
    OUTPUT_SWITCHES: Mapping[str, str] = {}  # output topic -> the publish_* parameter that switches it
    STATUS_OUTPUT: tuple[str, Any] = ("diagnostics", DiagnosticArray)  # every node's, about once a second
    OPTIONS: Sequence[str] = ()  # NodeOptions fields this node declares
    WITH_STEREO = False  # declares the processing parameters (StereoParams)
    MAX_FRAMES_AT_ONCE = 1  # worker threads; see `frames_at_once`

    def __init__(self, name: str, *, managed: bool = False, **kwargs: Any) -> None:
        """Declares the parameters. A plain node then configures and activates itself; a `managed` one
        (lifecycle) waits for its transitions, having created nothing else."""
        super().__init__(name, **kwargs)
        self.parameters = NodeParameters(
            self, self.OPTIONS, with_stereo=self.WITH_STEREO, on_change=self._settings_changed
        )
        self._options = self.parameters.settings.options
        self._spec = InputSpec(self.INPUTS, self.CALIBRATIONS, self.IMAGE_INPUTS, self.CAMERA_INFO_FILES)
        self.topics: list[str] = []
        self.extra_topics: list[str] = []  # inputs paired apart from the stereo set (a colour camera), set at configure
        self._new_diagnostics()
        self._outputs: list[Publisher] = []
        self._watches: list[SubscriberWatch] = []  # one per output: its incompatible-QoS warnings
        self._input_topics: InputTopics | None = None  # from configure to cleanup
        self._pairing: InputPairing | None = None  # while active
        self._io_timers: list[Timer] = []
        self._worker: LatestWorker | None = None
        self._sequence = itertools.count(1)  # input order of the matched sets
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
        """Calibration files and the publishers; nothing is received yet."""
        settings = self.parameters.settings
        self._input_topics = InputTopics(self, self._spec, settings.options)
        self.topics = self._input_topics.names
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
        assert self._input_topics is not None, "activate follows configure"
        self._pairing = InputPairing(
            self,
            self._spec,
            self._input_topics,
            settings.options,
            self.diagnostics,
            self.problems,
            self._submit,
            self.report_bug,
        )
        self._io_timers = [
            self.create_timer(1.0, self._publish_diagnostics),
            self.create_timer(QOS_RECHECK_S, partial(self._recheck_qos, False)),
            self.create_timer(1.0, self._flush_when_idle),
            self.create_timer(QOS_FULL_RECHECK_S, partial(self._recheck_qos, True)),
        ]
        self.open_extra_inputs()
        self._warn_unused_overrides()
        self.get_logger().info(f"ready: inputs {', '.join([*self.topics, *self.extra_topics])}")

    def _flush_when_idle(self) -> None:
        if self._pairing is not None and self._pairing.flush_when_idle():
            self.inputs_paused()

    def open_extra_inputs(self) -> None:
        """At activate, after the stereo inputs: a subclass subscribes the inputs it pairs apart
        (`extra_topics`, a colour camera), closing them in `deactivate_io`."""

    def inputs_paused(self) -> None:
        """The stereo inputs paused (IDLE_FLUSH_S without a message): a subclass gives up waiting for them."""

    def deactivate_io(self) -> None:
        """Unsubscribe, let the running frame finish, end the workers; half-paired sets are dropped."""
        if self._pairing is not None:
            self._pairing.close()
            self._pairing = None
        for timer in self._io_timers:
            self.destroy_timer(timer)
        self._io_timers = []
        self.stop_workers()

    def cleanup_io(self) -> None:
        """Back to the state after __init__: publishers and calibration files released."""
        self.deactivate_io()
        for publisher in self._outputs:
            self.destroy_output(publisher)
        self._outputs, self._watches = [], []
        self._input_topics = None

    @property
    def subscriptions_held(self) -> int:
        return len(self._pairing.subscriptions) if self._pairing is not None else 0

    def _new_diagnostics(self) -> None:
        """Fresh counters at each activation: a re-activated node reports nothing from before its pause."""
        self.diagnostics = NodeDiagnostics(self.get_fully_qualified_name(), [*self.topics, *self.extra_topics])
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

    def process(self, job: FrameJob, settings: Settings) -> dict[str, float] | None:
        """Turn one matched set into outputs; return per-stage times (ms) for diagnostics, or None when the
        rest of the frame was handed to another thread, which calls `finish_frame` when done."""
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

    def published(self, name: str, received_s: float) -> None:
        """Diagnostics: the age of a frame's `name` output as it went out, from the receipt of the frame's
        first input at `received_s` (what a subscriber of both sees as the node's delay)."""
        self.diagnostics.output_age(name, time.monotonic() - received_s)

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

    # ------------------------------------------------------------ internals

    def _submit(self, stamp_ns: int, messages: tuple[Any, ...], received_s: float) -> None:
        worker = self._worker
        if worker is not None:  # None: stopped since the set was paired
            worker.submit(FrameJob(next(self._sequence), stamp_ns, received_s, messages), received_s)

    def _settings_changed(self, settings: Settings) -> None:
        """Runs after a successful parameter change; the worker picks the new set up on its next frame."""
        old, new = self._options, settings.options
        self._options = new
        if self._worker is not None:
            self._worker.capacity = new.max_waiting_frames
            self._worker.parallel = self.frames_at_once(settings)
            self._worker.budget_s = new.max_latency_ms / 1000.0
        if self._pairing is not None:
            self._pairing.options_changed(old, new)

    def _recheck_qos(self, everything: bool) -> None:
        """Each input's reliability and publishers' types, each output's subscribers' QoS: looked at when
        their count moved, or `everything`."""
        inputs = self._pairing.subscriptions if self._pairing is not None else []
        endpoints: list[AdaptiveSubscription | SubscriberWatch] = [*inputs, *self._watches]
        for endpoint in endpoints:
            endpoint.check(everything=everything)

    def _run_frame(self, job: FrameJob) -> None:
        def work() -> None:
            settings = self.parameters.settings
            stage_ms = self.process(job, settings)
            if stage_ms is not None:
                self.finish_frame(job.stamp_ns, stage_ms)

        self.guarded(work)

    def _publish_diagnostics(self) -> None:
        silence = self.diagnostics.silent_inputs()
        if silence:
            self.problems.warn(silence, ("silent inputs",))
        header = make_header(RCLPY_TYPES, self.get_clock().now().nanoseconds, "")
        self._diagnostics_pub.publish(self.diagnostics.report(header))


def timed(stages: dict[str, float], name: str, start: float) -> None:
    stages[name] = (time.perf_counter() - start) * 1000.0
