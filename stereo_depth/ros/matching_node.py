"""The nodes that match a stereo pair (stereo_node, its lifecycle twin, disparity_node): a FrameStream that
is never None, its kernels warmed up before the first input, and what it returns published.

Two worker stages form a pipeline: the first decodes and matches (several frames at once with
`matching_threads`, a frame overtaken by a newer one dropped, never published after it), then, in input
order, publishes the image outputs and hands the frame's cloud job to the second, which turns the
disparity into depth and points2 and publishes them while the first already matches the next frame. So the
disparity goes out without waiting for the cloud, and a frame costs the longer of the two stages instead
of their sum. The second stage queues like the first (latest_worker.py: fewer waiting places as it falls
behind, the newest only under overload, `max_latency_ms` honoured); a disparity whose cloud it drops is
counted ("dropped clouds" in diagnostics).

With rgb_in_left set (stereo_node), the node also reads a colour camera (ros/colour_input.py) and the
second stage registers each frame's depth to the colour images paired with it (frames/registered.py),
after the frame's own outputs went out; the four registered outputs exist only then.

With left_in_base set, the node also reads the robot's odometry (ros/odom_input.py): the first stage waits
for a frame's odometry before the temporal filter, and logs one line where the odometry stops or jumps.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from typing import Any, NamedTuple

import numpy as np
from sensor_msgs.msg import CameraInfo, Image

from stereo_depth.core.calibration_check import check_rectified_pair
from stereo_depth.core.pipeline import StereoResult, warm_up_kernels
from stereo_depth.core.registration import compile_registration_kernels
from stereo_depth.core.threads import use_threads
from stereo_depth.frames import GEOMETRY_OUTPUTS, CloudJob
from stereo_depth.frames.odometry import odometry_note
from stereo_depth.frames.outputs import nearest_matchable_depth
from stereo_depth.frames.registered import REGISTERED_OUTPUTS, ColourNames, RegisteredJob, unset_pose_line
from stereo_depth.messages import RVL_FALLBACK_NOTE, compressed_depth_codec
from stereo_depth.options import NodeOptions, Settings
from stereo_depth.ros import signals
from stereo_depth.ros.colour_input import ColourInputs
from stereo_depth.ros.latest_worker import LatestWorker
from stereo_depth.ros.node_base import FrameJob
from stereo_depth.ros.odom_input import OdometryInput, wait_for_odometry
from stereo_depth.ros.qos import AdaptiveSubscription
from stereo_depth.ros.stream_node import StreamNode
from stereo_depth.sync import StereoSet


def stereo_inputs(image: str) -> tuple[tuple[str, Any], ...]:
    """A stereo camera's four inputs in synchronizer order (sync.STEREO_INPUTS): `image` is the image
    topic's last name (image_raw, image_rect)."""
    return (
        (f"left/{image}", Image),
        ("left/camera_info", CameraInfo),
        (f"right/{image}", Image),
        ("right/camera_info", CameraInfo),
    )


class CloudTask(NamedTuple):
    """A frame's cloud job on its way to the second stage, with what its diagnostics need."""

    job: CloudJob
    stamp_ns: int
    received_s: float
    stage_ms: dict[str, float]  # the first stage's


class RegisteredTask(NamedTuple):
    """Colour images paired when the stereo inputs paused (no frame of their own to go with)."""

    jobs: Sequence[RegisteredJob]
    received_s: float


class MatchingNode(StreamNode):
    """A subclass names its inputs, options and outputs; this class does the rest."""

    WITH_STEREO = True

    def __init__(self, name: str, **kwargs: Any) -> None:
        self._cloud_stage: LatestWorker | None = None  # started at activation
        self._checker: ThreadPoolExecutor | None = None
        self._check_idle = threading.Event()
        self._frames = 0
        self._order_lock = threading.Lock()
        self._published = 0  # sequence number of the newest set whose outputs went out
        self._colour: ColourInputs | None = None  # from configure to cleanup, with rgb_in_left set
        self._odometry: OdometryInput | None = None  # from configure to cleanup, with left_in_base set
        super().__init__(name, **kwargs)

    # ------------------------------------------------------------ registered depth (rgb_in_left)

    @property
    def registering(self) -> bool:
        return "rgb_in_left" in self.OPTIONS and self.parameters.settings.output.rgb_in_left.is_set

    def output_names(self) -> list[str]:
        names = super().output_names()
        return names if self.registering else [name for name in names if name not in REGISTERED_OUTPUTS]

    @property
    def with_odometry(self) -> bool:
        return "left_in_base" in self.OPTIONS and self.parameters.settings.output.left_in_base.is_set

    def configure_io(self) -> None:
        extra_topics = []
        if self.registering:
            self._colour = ColourInputs(self, self.parameters.settings.options)
            extra_topics += self._colour.names
        if self.with_odometry:
            self._odometry = OdometryInput(self)
            extra_topics.append(self._odometry.topic)
        self.extra_topics = extra_topics
        super().configure_io()
        if self._colour is not None:  # errors about the colour inputs name their topics
            self.stream.registration.names = ColourNames(*self._colour.names)

    def open_extra_inputs(self) -> None:
        if self._colour is not None:
            self._colour.open(
                self.parameters.settings.options,
                self.diagnostics,
                self.problems,
                self.stream.registration.add_colour,
                self.report_bug,
            )
            self._io_timers.append(self.create_timer(1.0, self._colour.flush_when_idle))
        if self._odometry is not None:
            self._odometry.open(
                self.parameters.settings.options, self.stream.odometry, self.diagnostics, self.report_bug
            )

    def deactivate_io(self) -> None:
        if self._colour is not None:
            self._colour.close()
        if self._odometry is not None:
            self._odometry.close()
        super().deactivate_io()

    def cleanup_io(self) -> None:
        super().cleanup_io()
        self._colour, self._odometry, self.extra_topics = None, None, []

    @property
    def subscriptions_held(self) -> int:
        return super().subscriptions_held + len(self._extra_subscriptions())

    def _extra_subscriptions(self) -> list[AdaptiveSubscription]:
        colour = self._colour.subscriptions if self._colour is not None else []
        return colour + (self._odometry.subscriptions if self._odometry is not None else [])

    def inputs_paused(self) -> None:
        """No frame will come to decide the colour images still waiting: they pair with the frames seen."""
        jobs = self.stream.registration.flush()
        if jobs and self._cloud_stage is not None:
            self._cloud_stage.submit(RegisteredTask(jobs, time.monotonic()))

    def _publish_registered(self, jobs: Sequence[RegisteredJob], received_s: float) -> None:
        """The registered outputs someone listens to, of each colour image paired; a bad colour input costs
        only these (one line naming its topic)."""
        self.diagnostics.registration(self.stream.registration.counters.unpaired_primary)
        wanted = [
            name
            for name in REGISTERED_OUTPUTS
            if name in self._output_publishers and self._output_publishers[name].get_subscription_count() > 0
        ]
        for job in jobs if wanted else ():
            self.guarded(lambda job=job: self.publish_outputs(job.run(wanted)[0], {}, received_s))  # type: ignore[misc]

    def _recheck_qos(self, everything: bool) -> None:
        super()._recheck_qos(everything)
        for subscription in self._extra_subscriptions():
            subscription.check(everything=everything)

    def _publish_diagnostics(self) -> None:
        """Also: a registered output subscribed while rgb_in_left is unset (the node has none) gets one
        throttled line naming the parameter."""
        super()._publish_diagnostics()
        if "rgb_in_left" in self.OPTIONS and not self.registering:
            asked = [name for name in REGISTERED_OUTPUTS if self.count_subscribers(self.resolve_topic_name(name))]
            if asked:
                self.problems.warn(unset_pose_line(asked), ("rgb_in_left unset",))

    # ------------------------------------------------------------ matching

    def frames_at_once(self, settings: Settings) -> int:
        return settings.options.matching_threads if "matching_threads" in self.OPTIONS else 1

    def start_workers(self) -> None:
        """The second stage and the calibration check first: the first stage's start can take seconds
        (the census core loads), and a signal then must find every thread that `stop_workers` ends."""
        options = self.parameters.settings.options
        if "calibration_check" in self.OPTIONS:  # beside the depth path, never in it: one at a time, skipped if busy
            self._checker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="calibration_check")
            self._check_idle.set()
            self._frames = 0
        if set(GEOMETRY_OUTPUTS) & set(dict(self.OUTPUTS)):
            self._cloud_stage = LatestWorker(
                self._run_cloud, self.diagnostics.cloud_dropped, options.max_waiting_frames
            )
            self._cloud_stage.budget_s = options.max_latency_ms / 1000.0
        super().start_workers()
        self._warm_up()

    def _warm_up(self) -> None:
        """The kernels the frames run, now rather than on the first frame."""
        settings = self.parameters.settings
        with signals.interruptible():  # numba's load or first compile: Ctrl-C need not wait for it
            if settings.stereo is not None and settings.stereo.matcher == "census_sgm":
                self.get_logger().info(
                    "census_sgm core: loading its machine code (compiled on the first start after installing, "
                    "one to two minutes; `stereo-depth compile` does that ahead)"
                )
            census = warm_up_kernels(settings.stereo)
            if self.registering:
                compile_registration_kernels()
            if census is not None:
                self.get_logger().info(f"census_sgm core ready in {census.seconds:.1f} s (numba cache: {census.cache})")

    def process(self, job: FrameJob, settings: Settings) -> dict[str, float] | None:
        """First stage: decode and match; then, in input order, the image outputs, and the cloud job handed
        to the second stage."""
        stream = self.stream
        stream.use(settings.stereo, settings.output)  # parameter changes, between two frames
        use_threads(settings.options.cpu_threads, self.frames_at_once(settings))
        matched = stream.matched(StereoSet.paired(job.stamp_ns, job.messages))
        stages = {"decode": matched.decode_ms}
        if self._odometry is not None and settings.stereo is not None and settings.stereo.temporal_filter:
            wait_for_odometry(stream.odometry, matched.frame.stamp_ns, settings.output.odom_wait_seconds)
        with self.outputs_in_order(job.sequence) as newest:
            if not newest:
                return None
            wanted = self._wanted(settings.options)
            out = stream.outputs(matched, wanted)
            if out.odometry_event is not None and self._odometry is not None:
                note = odometry_note(out.odometry_event, self._odometry.topic)
                self.problems.warn(note, ("odometry", out.odometry_event))
            if "right/image_rect" in wanted and (mismatch := camera_info_mismatch(settings)) is not None:
                self.problems.warn_once(mismatch)
            if out.calibration_changed:
                self.note_calibration(out.frame.camera)
            self._note_too_near(out.result, settings)
            self.publish_outputs(out.images, stages, job.received_s)
            if self._checker is not None:
                self._maybe_check_calibration(out.frame.stamp_ns, out.result.left_rect, out.result.right_rect, settings)
            if out.frame.camera.no_depth_reason is not None and self._cloud_stage is not None:
                self.problems.warn_once(out.frame.camera.no_depth_reason)  # disparity only
            if out.cloud is None or self._cloud_stage is None:
                return {**out.stage_ms, **stages}
            task = CloudTask(out.cloud, job.stamp_ns, job.received_s, {**out.stage_ms, **stages})
            self._cloud_stage.submit(task, job.received_s)
        return None

    def _note_too_near(self, result: StereoResult, settings: Settings) -> None:
        """Diagnostics' share of too-near pixels and nearest matchable depth; a throttled warning while many
        pixels stay too near."""
        if result.too_near is None or result.camera is None or settings.stereo is None:
            return
        nearest = nearest_matchable_depth(settings.stereo, result.camera)
        warning = self.diagnostics.too_near(float(np.count_nonzero(result.too_near)) / result.too_near.size, nearest)
        if warning:
            self.problems.warn(warning, ("too near for disparity_range",))

    @contextmanager
    def outputs_in_order(self, sequence: int) -> Iterator[bool]:
        """Hold while the frame of input order `sequence` publishes. Yields False, and counts the frame as
        dropped, when a newer set processed beside this one has published already: subscribers never see
        stamps go back."""
        with self._order_lock:
            if sequence < self._published:
                self.diagnostics.add_dropped(1)
                yield False
                return
            self._published = sequence
            yield True

    def _run_cloud(self, task: CloudTask | RegisteredTask) -> None:
        if isinstance(task, RegisteredTask):
            self._publish_registered(task.jobs, task.received_s)
            return
        registered: list[RegisteredJob] = []

        def work() -> None:
            cloud = task.job.run()
            registered.extend(cloud.registered)
            stages = task.stage_ms
            self.publish_outputs(cloud.messages, stages, task.received_s)
            self._note_compressed_depth_fallback(cloud.messages.get("depth/compressedDepth"))
            self.finish_frame(task.stamp_ns, {**cloud.stage_ms, **stages})

        self.guarded(work)
        if self.registering:
            self._publish_registered(registered, task.received_s)

    def _note_compressed_depth_fallback(self, compressed: Any) -> None:
        """One log line the first time rvl sends a frame as PNG (image_transport's decoder refuses its stream)."""
        wanted = self.parameters.settings.output.compressed_depth_format
        if compressed is not None and compressed_depth_codec(compressed) != wanted:
            self.get_logger().info(RVL_FALLBACK_NOTE, once=True)

    def _settings_changed(self, settings: Settings) -> None:
        old = self._options
        super()._settings_changed(settings)
        if self._colour is not None:
            self._colour.options_changed(old, settings.options)
        if self._odometry is not None:
            self._odometry.options_changed(settings.options)
        if self._cloud_stage is not None:  # None while a lifecycle node is not active
            self._cloud_stage.capacity = settings.options.max_waiting_frames
            self._cloud_stage.budget_s = settings.options.max_latency_ms / 1000.0

    def _maybe_check_calibration(
        self, stamp_ns: int, left_rect: np.ndarray, right_rect: np.ndarray, settings: Settings
    ) -> None:
        options = settings.options
        self._frames += 1
        if not options.calibration_check or self._frames % options.calibration_check_every_n_frames:
            return
        if not self._check_idle.is_set() or self._checker is None:
            return  # the previous check is still running: skip this one rather than queue
        self._check_idle.clear()
        # copies: the check outlives this frame, whose buffers the next frame may reuse
        self._checker.submit(self._check_calibration, stamp_ns, left_rect.copy(), right_rect.copy())

    def _check_calibration(self, stamp_ns: int, left_rect: np.ndarray, right_rect: np.ndarray) -> None:
        try:
            self.diagnostics.calibration(stamp_ns, check_rectified_pair(left_rect, right_rect))
        finally:
            self._check_idle.set()

    def stop_workers(self) -> None:
        super().stop_workers()  # the first stage: nothing new reaches the second
        if self._cloud_stage is not None:
            self._cloud_stage.stop()
            self._cloud_stage = None
        if self._checker is not None:
            self._checker.shutdown(wait=True, cancel_futures=True)
            self._checker = None

    def _wanted(self, options: NodeOptions) -> frozenset[str]:
        """The outputs switched on (publish_*) that someone listens to: only those are built."""
        return frozenset(
            name
            for name, publisher in self._output_publishers.items()
            if name not in self.OUTPUT_SWITCHES or self.wanted(publisher, getattr(options, self.OUTPUT_SWITCHES[name]))
        )


def camera_info_mismatch(settings: Settings) -> str | None:
    """Why left/ and right/camera_info do not describe the rectified images a visual odometry node pairs
    them with, if they do not."""
    stereo, options = settings.stereo, settings.options
    if stereo is not None and stereo.downsample > 1 and stereo.downsample_output == "processed":
        return (
            f"downsample_output: processed makes left/ and right/image_rect 1/{stereo.downsample} of the size "
            "left/ and right/camera_info describe; for stereo odometry set downsample_output: full"
        )
    if options.left_camera_info_url or options.right_camera_info_url:
        return (
            "with left/right_camera_info_url set no camera_info topic describes left/ and right/image_rect; for "
            "stereo odometry let the driver publish left/ and right/camera_info"
        )
    return None
