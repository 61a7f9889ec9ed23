"""stereo_node: raw stereo pair in, rectified left, disparity, depth and points2 out, in one process.

The node most users run: no intermediate topics, so no extra serialization of full-size images.
Topics and parameters are stereo_image_proc's (docs/parameters.md lists them); `profile:=stereo_image_proc`
gives its defaults.

Two worker stages form a pipeline: the first rectifies, matches and publishes the disparity (and the
rectified image and confidence); the second turns that disparity into depth and points2 and publishes
them, while the first already matches the next frame. So the disparity goes out without waiting for
the cloud, and a frame costs the longer of the two stages instead of their sum. The second stage
queues like the first (latest_worker.py: fewer waiting places as it falls behind, the newest only under
overload, `max_latency_ms` honoured); a disparity whose cloud it drops is counted ("dropped clouds" in
diagnostics). With `matching_threads:=2` the first stage matches two
frames at once, for matchers that leave cores idle; a frame overtaken by a newer one is dropped,
never published after it.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from sensor_msgs.msg import CameraInfo, CompressedImage, Image, PointCloud2
from stereo_msgs.msg import DisparityImage

from stereo_depth.core.calibration_check import check_rectified_pair
from stereo_depth.core.pipeline import StereoResult
from stereo_depth.frames import OUTPUTS, Geometry, OutputState, frame_outputs
from stereo_depth.messages import RVL_FALLBACK_NOTE, compressed_depth_codec
from stereo_depth.options import (
    CAMERA_OPTIONS,
    CLOUD_OPTIONS,
    DRIVER_FIX_OPTIONS,
    INPUT_OPTIONS,
    TEMPORAL_OPTIONS,
    NodeOptions,
    Settings,
)
from stereo_depth.ros.latest_worker import LatestWorker
from stereo_depth.ros.serialized_publish import publish
from stereo_depth.ros.stereo_io import StereoIONode, run_node, timed
from stereo_depth.ros.types import RCLPY_SERIALIZED
from stereo_depth.sync import STEREO_CALIBRATIONS, StereoSet

OUTPUT_TYPES = {
    "left/image_rect": Image,
    "left/image_rect_color": Image,
    "disparity": DisparityImage,
    "confidence": Image,
    "depth": Image,
    "depth/camera_info": CameraInfo,
    "depth/compressedDepth": CompressedImage,
    "points2": PointCloud2,
    "points2_clearing": PointCloud2,
}
# the publish_* parameter that switches each output on or off
SWITCHES = {
    "left/image_rect": "publish_rectified",
    "left/image_rect_color": "publish_rectified",
    "disparity": "publish_disparity",
    "confidence": "publish_confidence",
    "depth": "publish_depth",
    "depth/camera_info": "publish_depth",
    "depth/compressedDepth": "publish_depth",  # built only while someone subscribes, as image_transport's
    "points2": "publish_points",
    "points2_clearing": "publish_points_clearing",
}


class StereoNode(StereoIONode):
    INPUTS = (
        ("left/image_raw", Image),
        ("left/camera_info", CameraInfo),
        ("right/image_raw", Image),
        ("right/camera_info", CameraInfo),
    )
    CALIBRATIONS = tuple(STEREO_CALIBRATIONS.items())
    IMAGE_INPUTS = (0, 2)
    CAMERA_INFO_FILES = ((1, "left_camera_info_url"), (3, "right_camera_info_url"))
    OUTPUTS = tuple(OUTPUT_TYPES.items())
    OUTPUT_SWITCHES = SWITCHES
    OPTIONS = (
        *INPUT_OPTIONS,
        *CAMERA_OPTIONS,
        *DRIVER_FIX_OPTIONS,
        *CLOUD_OPTIONS,
        *TEMPORAL_OPTIONS,
        "depth_encoding",
        "clearing_max_depth",
        "compressed_depth_format",
        "compressed_depth_max_depth",
        "compressed_depth_quantization",
        "compressed_depth_png_level",
        "publish_rectified",
        "publish_disparity",
        "publish_depth",
        "publish_points",
        "publish_points_clearing",
        "publish_confidence",
        "calibration_check",
        "calibration_check_every_n_frames",
        "matching_threads",
        "cpu_threads",
    )
    WITH_STEREO = True
    MAX_FRAMES_AT_ONCE = 4

    def __init__(self, name: str = "stereo_node", **kwargs: Any) -> None:
        # started at activation, which a plain node runs inside super().__init__
        self._cloud_stage: LatestWorker | None = None
        self._checker: ThreadPoolExecutor | None = None
        super().__init__(name, **kwargs)

    def open_outputs(self) -> None:
        self._output_publishers = {name: self.declared_output(name) for name, _ in self.OUTPUTS}
        self._state = OutputState()  # its cloud buffer is reused frame to frame: publish() serializes first

    def start_workers(self) -> None:
        """The second stage and the calibration check first: the first stage's start can take seconds
        (the census core loads), and a signal then must find every thread that `stop_workers` ends."""
        # The calibration check runs beside the depth path, never in it: one at a time, skipped if busy.
        self._checker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="calibration_check")
        self._check_idle = threading.Event()
        self._check_idle.set()
        self._frames = 0
        options = self.parameters.settings.options
        # runs frames' cloud stage (frame_outputs), queued like the first stage
        self._cloud_stage = LatestWorker(
            self._run_cloud_stage, self.diagnostics.cloud_dropped, options.max_waiting_frames
        )
        self._cloud_stage.budget_s = options.max_latency_ms / 1000.0
        super().start_workers()

    def process(self, stamp_ns: int, messages: tuple[Any, ...], settings: Settings) -> dict[str, float] | None:
        """First stage: decode and match (several frames at once with matching_threads); then, in input
        order, the image outputs, and the cloud stage handed to the second thread (`frame_outputs`)."""
        assert self.pipeline is not None and settings.stereo is not None
        options = settings.options
        start = time.perf_counter()
        frame = self.read_frame(StereoSet.paired(stamp_ns, messages), settings, rectified=False)
        stages: dict[str, float] = {}
        timed(stages, "decode", start)
        result = self.match(frame)

        def publish_images(messages: dict[str, Any]) -> None:
            self._publish(messages, stages)
            self._maybe_check_calibration(frame.stamp_ns, result, options)
            if frame.camera.no_depth_reason is not None:  # frame_outputs sends disparity only
                self.problems.warn_once(frame.camera.no_depth_reason)

        def publish_cloud(messages: dict[str, Any], geometry: Geometry | None) -> None:
            del geometry  # the messages are all the node needs
            self._publish(messages, stages)
            compressed = messages.get("depth/compressedDepth")
            if compressed is not None and compressed_depth_codec(compressed) != settings.output.compressed_depth_format:
                self.get_logger().info(RVL_FALLBACK_NOTE, once=True)
            self.finish_frame(frame.stamp_ns, {**result.timings_ms, **stages})

        with self.outputs_in_order() as newest:
            if newest:
                frame_outputs(
                    RCLPY_SERIALIZED,
                    self.pipeline,
                    frame,
                    result,
                    settings.stereo,
                    settings.output,
                    self._wanted(OUTPUTS, options),
                    self._state,
                    publish_images,
                    publish_cloud,
                    run_cloud_stage=self._queue_cloud_stage,
                )
        return None

    def frames_at_once(self, settings: Settings) -> int:
        return settings.options.matching_threads

    def _queue_cloud_stage(self, stage: Callable[[], None]) -> None:
        received_s = self._frame.received_s  # the frame's receipt, for its outputs' age and latency budget
        assert self._cloud_stage is not None  # stopped only after the first stage, which calls this
        self._cloud_stage.submit((stage, received_s), received_s)

    def _run_cloud_stage(self, job: tuple[Callable[[], None], float]) -> None:
        stage, self._frame.received_s = job
        self.guarded(stage)

    def _settings_changed(self, settings: Settings) -> None:
        super()._settings_changed(settings)
        if self._cloud_stage is not None:  # None while a lifecycle node is not active
            self._cloud_stage.capacity = settings.options.max_waiting_frames
            self._cloud_stage.budget_s = settings.options.max_latency_ms / 1000.0

    def _maybe_check_calibration(self, stamp_ns: int, result: StereoResult, options: NodeOptions) -> None:
        self._frames += 1
        if not options.calibration_check or self._frames % options.calibration_check_every_n_frames:
            return
        if not self._check_idle.is_set():
            return  # the previous check is still running: skip this one rather than queue
        self._check_idle.clear()
        # copies: the check outlives this frame, whose buffers the next frame may reuse
        assert self._checker is not None  # stopped only after the first stage, which calls this
        self._checker.submit(self._check_calibration, stamp_ns, result.left_rect.copy(), result.right_rect.copy())

    def _check_calibration(self, stamp_ns: int, left_rect: Any, right_rect: Any) -> None:
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

    def _wanted(self, names: tuple[str, ...], options: NodeOptions) -> frozenset[str]:
        """The outputs switched on (publish_*) that someone listens to: only those are built."""
        return frozenset(n for n in names if self.wanted(self._output_publishers[n], getattr(options, SWITCHES[n])))

    def _publish(self, messages: dict[str, Any], stages: dict[str, float]) -> None:
        """Publish each output, timed on its own ("publish points2" in diagnostics): a slow subscriber of
        one topic shows as that topic's time."""
        for name, message in messages.items():
            start = time.perf_counter()
            publish(self._output_publishers[name], message)
            timed(stages, f"publish {name}", start)
            self.published(name)


def main(args: list[str] | None = None) -> int:
    return run_node(StereoNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
