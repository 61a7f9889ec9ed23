"""What the four nodes share: inputs -> synchronizer -> bounded worker -> outputs, plus `main()`.

Subscription callbacks only stamp, count and pair messages; the work runs on a worker thread that
takes complete sets oldest first from a short queue (`max_waiting_frames`). When frames arrive faster
than they can be processed the oldest waiting set is dropped (and counted), so latency stays bounded
instead of a backlog growing; the few waiting places absorb a busy machine's scheduling hiccups, which
a single slot turns into lost frames even at a rate the node easily sustains. A node may process
several sets at once (`frames_at_once`); its outputs still leave in input order.
OpenCV releases the GIL, so the executor keeps receiving while a frame is processed.
"""

from __future__ import annotations

import itertools
import signal
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from functools import partial
from types import FrameType
from typing import Any, TypeVar

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import CompressedImage

from stereo_depth.core.camera import CameraInfo, StereoCamera
from stereo_depth.core.params import StereoParams
from stereo_depth.core.pipeline import StereoPipeline, StereoResult
from stereo_depth.errors import CalibrationError, StereoDepthError
from stereo_depth.formats.camera_info_yaml import read_camera_info_url
from stereo_depth.frames import StereoFrame, decode_frame, decode_image, frame_camera, match_frame, named
from stereo_depth.messages import camera_info_to_msg, make_header, same_calibration, stamp_to_ns
from stereo_depth.ros.diagnostics import NodeDiagnostics
from stereo_depth.ros.parameters import NodeOptions, NodeParameters, Settings
from stereo_depth.ros.problems import ProblemLog, error_key
from stereo_depth.ros.qos import AdaptiveSubscription, output_qos
from stereo_depth.ros.transport import use_large_message_profile
from stereo_depth.ros.types import RCLPY_TYPES
from stereo_depth.sync import Synchronizer

T = TypeVar("T")
QOS_RECHECK_S = 0.25  # reaction to a publisher's matched / incompatible-QoS event
QOS_FULL_RECHECK_S = 2.0  # fallback: look at every input's publishers
# No input for this long: sets waiting only for a camera_info go out. Longer than a reliable writer takes
# to repair a lost sample (Fast DDS sends its heartbeat every 3 s), so a repaired camera_info still counts.
IDLE_FLUSH_S = 5.0


class LatestWorker:
    """Runs jobs on `threads` threads, oldest first, at most `parallel` at once; at most `capacity`
    wait, and one more replaces the oldest waiting job (`on_replaced`). Capacity 1: always the newest
    job. Both limits are read as jobs come and go, so a parameter change applies to the next job."""

    def __init__(
        self, run: Callable[[Any], None], on_replaced: Callable[[], None], capacity: int = 1, threads: int = 1
    ) -> None:
        self._run = run
        self._on_replaced = on_replaced
        self.capacity = capacity
        self.parallel = 1
        self._running = 0
        self._cond = threading.Condition()
        self._pending: deque[Any] = deque()
        self._stopped = False
        self._threads = [
            threading.Thread(target=self._loop, name=f"stereo_depth-worker-{i}", daemon=True) for i in range(threads)
        ]
        for thread in self._threads:
            thread.start()

    def submit(self, job: Any) -> None:
        with self._cond:
            while len(self._pending) >= max(self.capacity, 1):
                self._pending.popleft()
                self._on_replaced()
            self._pending.append(job)
            self._cond.notify_all()

    def stop(self) -> None:
        """Let the running jobs finish, discard the waiting ones, end the threads."""
        with self._cond:
            self._stopped = True
            self._pending.clear()
            self._cond.notify_all()
        for thread in self._threads:
            thread.join(timeout=30.0)

    def _loop(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._stopped or (bool(self._pending) and self._running < self.parallel))
                if self._stopped:
                    return
                job = self._pending.popleft()
                self._running += 1
            try:
                self._run(job)
            finally:
                with self._cond:
                    self._running -= 1
                    self._cond.notify_all()


class StereoIONode(Node):
    """Base of the four nodes. A subclass names its inputs and options and implements `process`."""

    INPUTS: Sequence[tuple[str, Any]] = ()  # (relative topic, message class), in synchronizer order
    CALIBRATIONS: Sequence[tuple[int, int]] = ()  # (camera_info input, the input whose stamp it carries)
    IMAGE_INPUTS: Sequence[int] = ()  # inputs that image_transport:=compressed reads from <topic>/compressed
    # (camera_info input, the option naming a file that replaces it; its image input is in CALIBRATIONS)
    CAMERA_INFO_FILES: Sequence[tuple[int, str]] = ()
    OPTIONS: Sequence[str] = ()  # NodeOptions fields this node declares
    WITH_STEREO = False  # declares the processing parameters (StereoParams) and owns a pipeline
    MAX_FRAMES_AT_ONCE = 1  # worker threads; see `frames_at_once`

    def __init__(self, name: str, **kwargs: Any) -> None:
        super().__init__(name, **kwargs)
        self.parameters = NodeParameters(
            self, self.OPTIONS, with_stereo=self.WITH_STEREO, on_change=self._settings_changed
        )
        settings = self.parameters.settings
        inputs = input_specs(self.INPUTS, self.IMAGE_INPUTS, settings.options)
        self._info_files = camera_info_files(self.CAMERA_INFO_FILES, dict(self.CALIBRATIONS), settings.options)
        self.topics = [
            self._info_files[index][0] if index in self._info_files else self.resolve_topic_name(topic)
            for index, (topic, _) in enumerate(inputs)
        ]
        self.diagnostics = NodeDiagnostics(self.get_fully_qualified_name(), self.topics)
        self.problems = ProblemLog(self.get_logger(), self.diagnostics)
        self.pipeline = StereoPipeline(settings.stereo) if settings.stereo is not None else None
        self._options = settings.options
        self._sync_lock = threading.Lock()
        self._sync = self._new_sync(settings.options)
        self._last_input_s = 0.0  # monotonic time of the newest input message; 0 once flushed
        self._inputs = [
            AdaptiveSubscription(
                self,
                msg_type,
                topic,
                partial(self._on_message, index),
                policy=settings.options.reliability,
                depth=settings.options.queue_size,
                on_lost=partial(self.diagnostics.input_lost, self.topics[index]),
            )
            for index, (topic, msg_type) in enumerate(inputs)
            if index not in self._info_files
        ]
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, "diagnostics", 10)
        self._worker = LatestWorker(
            self._run_frame,
            partial(self.diagnostics.add_dropped, 1),
            settings.options.max_waiting_frames,
            threads=self.MAX_FRAMES_AT_ONCE,
        )
        self._worker.parallel = self.frames_at_once(settings)
        self._sequence = itertools.count(1)  # input order of the matched sets
        self._order_lock = threading.Lock()
        self._published = 0  # sequence number of the newest set whose outputs went out
        self._frame = threading.local()  # the sequence number of the set this worker thread processes
        self.create_timer(1.0, self._publish_diagnostics)
        self.create_timer(QOS_RECHECK_S, partial(self._recheck_qos, False))
        self.create_timer(1.0, self._flush_when_idle)
        self.create_timer(QOS_FULL_RECHECK_S, partial(self._recheck_qos, True))
        self.get_logger().info(f"ready: inputs {', '.join(self.topics)}")

    # ------------------------------------------------------------ to implement / use in subclasses

    def process(self, messages: tuple[Any, ...], settings: Settings) -> dict[str, float] | None:
        """Turn one matched set into outputs; return per-stage times (ms) for diagnostics, or None when
        the rest of the frame was handed to another thread, which calls `finish_frame` when done."""
        raise NotImplementedError

    def frames_at_once(self, settings: Settings) -> int:
        """How many sets may be processed at once (at most MAX_FRAMES_AT_ONCE); 1 unless overridden."""
        return 1

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

    def output(self, msg_type: Any, topic: str) -> Publisher:
        return self.create_publisher(msg_type, topic, output_qos())

    @staticmethod
    def wanted(publisher: Publisher, enabled: bool) -> bool:
        """Worth computing and serializing only when switched on and someone listens."""
        return enabled and publisher.get_subscription_count() > 0

    def read_input(self, index: int, convert: Callable[[Any], T], msg: Any) -> T:
        """`convert(msg)`, with the input's topic named in any error it raises."""
        return named(self.topics[index], convert, msg)

    def read_image(self, index: int, msg: Any, settings: Settings) -> Any:
        return named(self.topics[index], decode_image, msg, settings.output.max_image_pixels)

    def stereo_camera(self, left_index: int, left_msg: Any, right_index: int, right_msg: Any) -> StereoCamera:
        """The cached StereoCamera; calibration errors name both camera_info topics."""
        assert self.pipeline is not None
        loaded = self.pipeline.calibrations_built
        names = (self.topics[left_index], self.topics[right_index])
        camera = frame_camera(self.pipeline, left_msg, right_msg, names)
        self._note_calibration(loaded, camera, names)
        return camera

    def read_frame(self, messages: tuple[Any, ...], settings: Settings, *, rectified: bool) -> StereoFrame:
        """`decode_frame` of (left image, left info, right image, right info), errors naming the topics."""
        assert self.pipeline is not None
        loaded = self.pipeline.calibrations_built
        frame = decode_frame(messages, self.pipeline, settings.output, rectified=rectified, names=self.topics)
        self._note_calibration(loaded, frame.camera, (self.topics[1], self.topics[3]))
        return frame

    def match(self, frame: StereoFrame) -> StereoResult:
        """`match_frame`, with both image topics named in any error it raises."""
        assert self.pipeline is not None
        return match_frame(self.pipeline, frame, self.topics)

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
            if not self.context.ok():
                return  # shutting down: publishers are gone
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

    def _on_message(self, index: int, msg: Any) -> None:
        stamp = stamp_to_ns(msg.header.stamp)
        topic = self.topics[index]
        if stamp == 0:
            self.problems.skipped(
                f"{topic}: header.stamp is zero, message skipped; the driver must stamp every image and "
                "camera_info with its capture time, or left and right cannot be paired",
                ("zero stamp", topic),
            )
            return
        self.diagnostics.input_received(topic, stamp)
        self._last_input_s = time.monotonic()
        self._pair(lambda sync: sync.add(index, stamp, msg), topic, stamp)
        for info_index, (_, image_index, info) in self._info_files.items():
            if image_index == index:  # the file's calibration, stamped as this image, takes the topic's place
                self._on_message(info_index, camera_info_to_msg(RCLPY_TYPES, msg.header, info))

    def _pair(self, step: Callable[[Synchronizer], list[tuple[int, tuple[Any, ...]]]], topic: str, stamp: int) -> None:
        """One synchronizer step; its counters go to diagnostics per topic, the sets to the worker."""
        with self._sync_lock:
            before = self._sync.counters.copy()
            sets = step(self._sync)
            change = self._sync.counters.since(before)
        self.diagnostics.sync_changed(change)
        if change.stale:
            self._stale_stamp(topic, stamp)
        if change.time_jumps:
            self._time_jump(topic, stamp)
        for stamp_ns, messages in sets:
            self._worker.submit((next(self._sequence), stamp_ns, messages))

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
        self._worker.capacity = new.max_waiting_frames
        self._worker.parallel = self.frames_at_once(settings)
        if any(getattr(old, n) != getattr(new, n) for n in ("queue_size", "approximate_sync", "tolerance_ns")):
            with self._sync_lock:
                self._sync.reset()
                self._sync = self._new_sync(new)
        if (old.reliability, old.queue_size) != (new.reliability, new.queue_size):
            for subscription in self._inputs:
                subscription.configure(new.reliability, new.queue_size)

    def _recheck_qos(self, everything: bool) -> None:
        for subscription in self._inputs:
            if everything or subscription.recheck_requested:
                subscription.recheck()

    def _run_frame(self, job: tuple[int, int, tuple[Any, ...]]) -> None:
        self._frame.sequence, stamp_ns, messages = job

        def work() -> None:
            settings = self.parameters.settings
            if self.pipeline is not None and settings.stereo is not None:
                self._use_params(self.pipeline, settings.stereo)
            stage_ms = self.process(messages, settings)
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
        so that none of them publishes while the node is being destroyed."""
        self._worker.stop()

    def destroy_node(self) -> None:
        self.stop_workers()
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


def run_node(factory: Callable[[], Node], args: list[str] | None = None) -> int:
    """rclpy Jazzy's main(). SIGINT / SIGTERM raise SystemExit(0) (`exit_quietly_on_signals`), so the
    `finally` below stops the worker and destroys the node before the process ends with 0.
    A node that cannot start (bad --ros-args, --params-file or parameter value) says why in one
    line and exits with 2, rather than run with part of its configuration."""
    exit_quietly_on_signals()
    profile = use_large_message_profile()
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except RuntimeError as exc:  # rcl's error (unreadable --params-file, malformed --ros-args) is one
        rclpy.logging.get_logger("stereo_depth").error(f"cannot start: {_rcl_reason(exc)}")
        return 2
    node: Node | None = None
    code = 0
    try:
        node = factory()
        if profile is not None:
            node.get_logger().info(
                f"Fast DDS: large-message profile {profile} for this process (no profile was exported); see "
                'README "Inputs and outputs over DDS"'
            )
        rclpy.spin(node)  # the diagnostics / QoS timers wake it often enough for signals
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (StereoDepthError, InvalidParameterValueException, InvalidParameterTypeException) as exc:
        rclpy.logging.get_logger("stereo_depth").error(f"cannot start: {exc}")
        code = 2
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code


def exit_quietly_on_signals() -> None:
    """Ctrl-C or SIGTERM end a node with exit code 0 and no traceback, whenever they arrive. The handler
    stays in charge after `rclpy.init` (which is told to install none): raising SystemExit between two
    bytecodes of the main thread unwinds through `run_node`'s cleanup without racing rclpy's C code,
    which rclpy's own SIGTERM handler does when it shuts the context down from another thread."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _exit_quietly)


def _exit_quietly(signum: int, frame: FrameType | None) -> None:
    del signum, frame
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_IGN)  # a second signal must not interrupt the cleanup
    raise SystemExit(0)


def _rcl_reason(exc: Exception) -> str:
    """rcl's message on one line, without the C source locations it appends (", at file.c:123")."""
    return " ".join(str(exc).split(", at /")[0].split())
