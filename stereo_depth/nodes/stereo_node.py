"""stereo_node: raw stereo pair in, rectified left, disparity, depth and points2 out, in one process.

The node most users run: no intermediate topics, so no extra serialization of full-size images.
Topics and parameters are stereo_image_proc's (see README); `profile:=stereo_image_proc` gives its
defaults.

Two worker stages form a pipeline: the first rectifies, matches and publishes the disparity (and the
rectified image and confidence); the second turns that disparity into depth and points2 and publishes
them, while the first already matches the next frame. So the disparity goes out without waiting for
the cloud, and a frame costs the longer of the two stages instead of their sum. The second stage keeps
only the newest disparity too: one it could not start before a newer one arrived is dropped and
counted ("dropped clouds" in diagnostics). With `matching_threads:=2` the first stage matches two
frames at once, for matchers that leave cores idle; a frame overtaken by a newer one is dropped,
never published after it.
"""

from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from stereo_msgs.msg import DisparityImage

from stereo_depth.core.calibration_check import check_rectified_pair
from stereo_depth.core.pipeline import StereoResult
from stereo_depth.core.temporal import compile_kernels
from stereo_depth.frames import (
    GEOMETRY_OUTPUTS,
    IMAGE_OUTPUTS,
    OutputOptions,
    OutputState,
    StereoFrame,
    filter_over_time,
    geometry_outputs,
    image_outputs,
    result_geometry,
)
from stereo_depth.ros.parameters import CLOUD_OPTIONS, INPUT_OPTIONS, NodeOptions, Settings
from stereo_depth.ros.stereo_io import LatestWorker, StereoIONode, run_node, timed
from stereo_depth.ros.types import RCLPY_TYPES
from stereo_depth.settings import CAMERA_OPTIONS, TEMPORAL_OPTIONS

OUTPUT_TYPES = {
    "left/image_rect": Image,
    "left/image_rect_color": Image,
    "disparity": DisparityImage,
    "confidence": Image,
    "depth": Image,
    "depth/camera_info": CameraInfo,
    "points2": PointCloud2,
}
# the publish_* parameter that switches each output on or off
SWITCHES = {
    "left/image_rect": "publish_rectified",
    "left/image_rect_color": "publish_rectified",
    "disparity": "publish_disparity",
    "confidence": "publish_confidence",
    "depth": "publish_depth",
    "depth/camera_info": "publish_depth",
    "points2": "publish_points",
}


class StereoNode(StereoIONode):
    INPUTS = (
        ("left/image_raw", Image),
        ("left/camera_info", CameraInfo),
        ("right/image_raw", Image),
        ("right/camera_info", CameraInfo),
    )
    CALIBRATIONS = ((1, 0), (3, 2))
    IMAGE_INPUTS = (0, 2)
    CAMERA_INFO_FILES = ((1, "left_camera_info_url"), (3, "right_camera_info_url"))
    OPTIONS = (
        *INPUT_OPTIONS,
        *CAMERA_OPTIONS,
        *CLOUD_OPTIONS,
        *TEMPORAL_OPTIONS,
        "depth_encoding",
        "publish_rectified",
        "publish_disparity",
        "publish_depth",
        "publish_points",
        "publish_confidence",
        "calibration_check",
        "calibration_check_every_n_frames",
        "matching_threads",
    )
    WITH_STEREO = True
    MAX_FRAMES_AT_ONCE = 4

    def __init__(self) -> None:
        super().__init__("stereo_node")
        self._output_publishers = {name: self.output(msg_type, name) for name, msg_type in OUTPUT_TYPES.items()}
        self._state = OutputState()  # its cloud buffer is reused frame to frame: publish() serializes first
        # The calibration check runs beside the depth path, never in it: one at a time, skipped if busy.
        self._checker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="calibration_check")
        self._check_idle = threading.Event()
        self._check_idle.set()
        self._frames = 0
        self._geometry = LatestWorker(self._geometry_stage, self.diagnostics.add_dropped_cloud)
        if self.parameters.settings.output.temporal_filter:
            compile_kernels()  # now, not on the first frame

    def process(self, messages: tuple[Any, ...], settings: Settings) -> dict[str, float] | None:
        assert self.pipeline is not None and settings.stereo is not None
        options = settings.options
        start = time.perf_counter()
        frame = self.read_frame(messages, settings, rectified=False)
        stages: dict[str, float] = {}
        timed(stages, "decode", start)
        result = self.match(frame)
        with self.outputs_in_order() as newest:
            if not newest:
                return None
            filter_over_time(self._state.temporal, frame, result, settings.output)  # frames in stamp order here
            wanted = self._wanted(IMAGE_OUTPUTS, options)
            self._publish(image_outputs(RCLPY_TYPES, frame.header, result, settings.stereo, wanted), stages)
            self._maybe_check_calibration(frame.stamp_ns, result, options)
            wanted = self._state.cloud_rate.wanted(
                self._wanted(GEOMETRY_OUTPUTS, options), frame.stamp_ns, settings.output
            )
            if not wanted:
                return {**result.timings_ms, **stages}
            self._geometry.submit((frame, result, stages, settings.output, wanted))
        return None

    def frames_at_once(self, settings: Settings) -> int:
        return settings.options.matching_threads

    def _geometry_stage(
        self, job: tuple[StereoFrame, StereoResult, dict[str, float], OutputOptions, frozenset[str]]
    ) -> None:
        """Second stage: depth and points2 of a published disparity, then the frame is done."""
        frame, result, stages, output, wanted = job

        def work() -> None:
            assert self.pipeline is not None
            geometry = result_geometry(self.pipeline, frame, result)  # times "depth"
            start = time.perf_counter()
            messages = geometry_outputs(RCLPY_TYPES, frame.header, geometry, output, wanted, self._state)
            timed(stages, "points", start)  # the depth image and points2 messages, as `process` times it
            self._publish(messages, stages)
            self.finish_frame(frame.stamp_ns, {**result.timings_ms, **stages})

        self.guarded(work)

    def _maybe_check_calibration(self, stamp_ns: int, result: StereoResult, options: NodeOptions) -> None:
        self._frames += 1
        if not options.calibration_check or self._frames % options.calibration_check_every_n_frames:
            return
        if not self._check_idle.is_set():
            return  # the previous check is still running: skip this one rather than queue
        self._check_idle.clear()
        # copies: the check outlives this frame, whose buffers the next frame may reuse
        self._checker.submit(self._check_calibration, stamp_ns, result.left_rect.copy(), result.right_rect.copy())

    def _check_calibration(self, stamp_ns: int, left_rect: Any, right_rect: Any) -> None:
        try:
            self.diagnostics.calibration(stamp_ns, check_rectified_pair(left_rect, right_rect))
        finally:
            self._check_idle.set()

    def stop_workers(self) -> None:
        super().stop_workers()  # the first stage: nothing new reaches the second
        self._geometry.stop()
        self._checker.shutdown(wait=True, cancel_futures=True)

    def _wanted(self, names: tuple[str, ...], options: NodeOptions) -> frozenset[str]:
        """The outputs switched on (publish_*) that someone listens to: only those are built."""
        return frozenset(n for n in names if self.wanted(self._output_publishers[n], getattr(options, SWITCHES[n])))

    def _publish(self, messages: dict[str, Any], stages: dict[str, float]) -> None:
        """Publish each output, timed on its own ("publish points2" in diagnostics): a slow subscriber of
        one topic shows as that topic's time."""
        for name, message in messages.items():
            start = time.perf_counter()
            self._output_publishers[name].publish(message)
            timed(stages, f"publish {name}", start)


def main(args: list[str] | None = None) -> int:
    return run_node(StereoNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
