"""What the four nodes share: inputs -> synchronizer -> one-slot worker -> outputs, plus `main()`.

Subscription callbacks only stamp, count and pair messages; the work runs on one worker thread that
always takes the newest complete set. When frames arrive faster than they can be processed the
older waiting set is replaced (and counted), so latency stays bounded instead of a backlog growing.
OpenCV releases the GIL, so the executor keeps receiving while a frame is processed.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from functools import partial
from typing import Any, TypeVar

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.signals import SignalHandlerOptions

from stereo_depth.core.camera import StereoCamera
from stereo_depth.core.matching import valid_window
from stereo_depth.core.params import StereoParams
from stereo_depth.core.pipeline import StereoPipeline
from stereo_depth.errors import StereoDepthError
from stereo_depth.messages import (
    camera_info_from_msg,
    disparity_to_msg,
    image_to_pipeline,
    make_header,
    points_to_cloud,
    stamp_to_ns,
)
from stereo_depth.ros.diagnostics import NodeDiagnostics
from stereo_depth.ros.parameters import NodeOptions, NodeParameters, Settings
from stereo_depth.ros.qos import AdaptiveSubscription, output_qos
from stereo_depth.ros.types import RCLPY_TYPES
from stereo_depth.sync import Synchronizer

T = TypeVar("T")
QOS_RECHECK_S = 0.25  # reaction to a publisher's matched / incompatible-QoS event
QOS_FULL_RECHECK_S = 2.0  # fallback: look at every input's publishers


class LatestWorker:
    """Runs jobs on one thread; a job submitted while another waits replaces it (`on_replaced`)."""

    def __init__(self, run: Callable[[Any], None], on_replaced: Callable[[], None]) -> None:
        self._run = run
        self._on_replaced = on_replaced
        self._cond = threading.Condition()
        self._pending: Any = None
        self._stopped = False
        self._thread = threading.Thread(target=self._loop, name="stereo_depth-worker", daemon=True)
        self._thread.start()

    def submit(self, job: Any) -> None:
        with self._cond:
            if self._pending is not None:
                self._on_replaced()
            self._pending = job
            self._cond.notify()

    def stop(self) -> None:
        """Let the running job finish, discard the waiting one, end the thread."""
        with self._cond:
            self._stopped = True
            self._pending = None
            self._cond.notify()
        self._thread.join(timeout=30.0)

    def _loop(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._stopped or self._pending is not None)
                if self._stopped:
                    return
                job, self._pending = self._pending, None
            self._run(job)


class StereoIONode(Node):
    """Base of the four nodes. A subclass names its inputs and options and implements `process`."""

    INPUTS: Sequence[tuple[str, Any]] = ()  # (relative topic, message class), in synchronizer order
    OPTIONS: Sequence[str] = ()  # NodeOptions fields this node declares
    WITH_STEREO = False  # declares the processing parameters (StereoParams) and owns a pipeline

    def __init__(self, name: str, **kwargs: Any) -> None:
        super().__init__(name, **kwargs)
        self.topics = [self.resolve_topic_name(topic) for topic, _ in self.INPUTS]
        self.diagnostics = NodeDiagnostics(self.get_fully_qualified_name(), self.topics)
        self.parameters = NodeParameters(
            self, self.OPTIONS, with_stereo=self.WITH_STEREO, on_change=self._settings_changed
        )
        settings = self.parameters.settings
        self.pipeline = StereoPipeline(settings.stereo) if settings.stereo is not None else None
        self._options = settings.options
        self._sync_lock = threading.Lock()
        self._sync = self._new_sync(settings.options)
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
            for index, (topic, msg_type) in enumerate(self.INPUTS)
        ]
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, "diagnostics", 10)
        self._worker = LatestWorker(self._run_frame, partial(self.diagnostics.add_dropped, 1))
        self.create_timer(1.0, self._publish_diagnostics)
        self.create_timer(QOS_RECHECK_S, partial(self._recheck_qos, False))
        self.create_timer(QOS_FULL_RECHECK_S, partial(self._recheck_qos, True))
        self.get_logger().info(f"ready: inputs {', '.join(self.topics)}")

    # ------------------------------------------------------------ to implement / use in subclasses

    def process(self, messages: tuple[Any, ...], settings: Settings) -> dict[str, float]:
        """Turn one matched set into outputs; return per-stage times (ms) for diagnostics."""
        raise NotImplementedError

    def output(self, msg_type: Any, topic: str) -> Publisher:
        return self.create_publisher(msg_type, topic, output_qos())

    @staticmethod
    def wanted(publisher: Publisher, enabled: bool) -> bool:
        """Worth computing and serializing only when switched on and someone listens."""
        return enabled and publisher.get_subscription_count() > 0

    def read_input(self, index: int, convert: Callable[[Any], T], msg: Any) -> T:
        """`convert(msg)`, with the input's topic named in any error it raises."""
        try:
            return convert(msg)
        except StereoDepthError as exc:
            raise type(exc)(f"{self.topics[index]}: {exc}") from exc

    def read_image(self, index: int, msg: Any, options: NodeOptions) -> Any:
        return self.read_input(index, partial(image_to_pipeline, max_pixels=options.max_image_pixels), msg)

    def stereo_camera(self, left_index: int, left_msg: Any, right_index: int, right_msg: Any) -> StereoCamera:
        """The cached StereoCamera; calibration errors name both camera_info topics."""
        assert self.pipeline is not None
        left = self.read_input(left_index, camera_info_from_msg, left_msg)
        right = self.read_input(right_index, camera_info_from_msg, right_msg)
        try:
            return self.pipeline.camera_for(left, right)
        except StereoDepthError as exc:
            topics = f"left = {self.topics[left_index]}, right = {self.topics[right_index]}"
            raise type(exc)(f"{exc} ({topics})") from exc

    # ------------------------------------------------------------ internals

    def _new_sync(self, options: NodeOptions) -> Synchronizer:
        return Synchronizer(
            len(self.INPUTS),
            queue_size=options.queue_size,
            approximate=options.approximate_sync,
            tolerance_ns=options.tolerance_ns,
        )

    def _on_message(self, index: int, msg: Any) -> None:
        stamp = stamp_to_ns(msg.header.stamp)
        self.diagnostics.input_received(self.topics[index], stamp)
        with self._sync_lock:
            before = self._sync.counters.dropped + self._sync.counters.stale
            sets = self._sync.add(index, stamp, msg)
            self.diagnostics.add_unmatched(self._sync.counters.dropped + self._sync.counters.stale - before)
        for stamp_ns, messages in sets:
            self._worker.submit((stamp_ns, messages))

    def _settings_changed(self, settings: Settings) -> None:
        """Runs after a successful parameter change; the worker picks the new set up on its next frame."""
        old, new = self._options, settings.options
        self._options = new
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

    def _run_frame(self, job: tuple[int, tuple[Any, ...]]) -> None:
        stamp_ns, messages = job
        settings = self.parameters.settings
        try:
            if self.pipeline is not None and settings.stereo is not None:
                self._use_params(self.pipeline, settings.stereo)
            stage_ms = self.process(messages, settings)
        except StereoDepthError as exc:
            self.diagnostics.error(str(exc))
            self.get_logger().warning(f"frame skipped: {exc}", throttle_duration_sec=5.0)
            return
        except Exception as exc:  # a bug, not bad input: say so, keep serving the next frames
            if not self.context.ok():
                return  # shutting down: publishers are gone
            self.diagnostics.error(f"internal error: {exc!r}")
            self.get_logger().error(f"internal error, please report: {exc!r}", throttle_duration_sec=5.0)
            return
        latency_s = (self.get_clock().now().nanoseconds - stamp_ns) / 1e9
        self.diagnostics.frame_done(stage_ms, latency_s)

    @staticmethod
    def _use_params(pipeline: StereoPipeline, params: StereoParams) -> None:
        """Parameter changes reach the pipeline here, on the worker thread, between two frames."""
        if pipeline.params is not params:
            pipeline.set_params(params)

    def _publish_diagnostics(self) -> None:
        header = make_header(RCLPY_TYPES, self.get_clock().now().nanoseconds, "")
        self._diagnostics_pub.publish(self.diagnostics.report(header))

    def destroy_node(self) -> None:
        self._worker.stop()
        super().destroy_node()


def disparity_message(header: Any, disparity: Any, camera: StereoCamera, params: StereoParams) -> Any:
    """DisparityImage with the matcher's real valid window and resolution (1/16 px per downsample step)."""
    height, width = disparity.shape
    return disparity_to_msg(
        RCLPY_TYPES,
        header,
        disparity,
        camera,
        params.min_disparity,
        params.disparity_range,
        valid_window(width, height, params),
        delta_d=params.downsample / 16.0,
    )


def cloud_message(header: Any, points: Any, image: Any, options: NodeOptions) -> Any:
    """Organized PointCloud2; colour from the rectified left image (grey when the camera is mono)."""
    color = image if options.use_color else None
    return points_to_cloud(RCLPY_TYPES, header, points, color, avoid_padding=options.avoid_point_cloud_padding)


def timed(stages: dict[str, float], name: str, start: float) -> None:
    stages[name] = (time.perf_counter() - start) * 1000.0


def run_node(factory: Callable[[], Node], args: list[str] | None = None) -> int:
    """rclpy Jazzy's main(). SIGINT / SIGTERM raise SystemExit(0) (see stereo_depth.nodes), so the
    `finally` below stops the worker and destroys the node before the process ends with 0."""
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    node: Node | None = None
    code = 0
    try:
        node = factory()
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
