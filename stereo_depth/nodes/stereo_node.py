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
from stereo_depth.messages import CloudBuffer, array_to_image, stamp_to_ns
from stereo_depth.outputs import disparity_message
from stereo_depth.ros.parameters import CAMERA_OPTIONS, CLOUD_OPTIONS, INPUT_OPTIONS, NodeOptions, Settings
from stereo_depth.ros.stereo_io import LatestWorker, StereoIONode, cloud_message, run_node, timed
from stereo_depth.ros.types import RCLPY_TYPES


class StereoNode(StereoIONode):
    INPUTS = (
        ("left/image_raw", Image),
        ("left/camera_info", CameraInfo),
        ("right/image_raw", Image),
        ("right/camera_info", CameraInfo),
    )
    IMAGE_INPUTS = (0, 2)
    CAMERA_INFO_FILES = ((1, "left_camera_info_url", 0), (3, "right_camera_info_url", 2))
    OPTIONS = (
        *INPUT_OPTIONS,
        *CAMERA_OPTIONS,
        *CLOUD_OPTIONS,
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
        self._rect = self.output(Image, "left/image_rect")
        self._rect_color = self.output(Image, "left/image_rect_color")
        self._disparity = self.output(DisparityImage, "disparity")
        self._depth = self.output(Image, "depth")
        self._points = self.output(PointCloud2, "points2")
        self._cloud_buffer = CloudBuffer()  # reused frame to frame: publish() serializes before returning
        self._confidence = self.output(Image, "confidence")
        # The calibration check runs beside the depth path, never in it: one at a time, skipped if busy.
        self._checker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="calibration_check")
        self._check_idle = threading.Event()
        self._check_idle.set()
        self._frames = 0
        self._geometry = LatestWorker(self._geometry_stage, self.diagnostics.add_dropped_cloud)

    def process(self, messages: tuple[Any, ...], settings: Settings) -> dict[str, float] | None:
        assert self.pipeline is not None and settings.stereo is not None
        header = messages[0].header
        options = settings.options
        start = time.perf_counter()
        left, right, camera = self.read_stereo_pair(messages, options)
        stages: dict[str, float] = {}
        timed(stages, "decode", start)
        result = self.match_pair(left, right, camera)
        with self.outputs_in_order() as newest:
            if not newest:
                return None
            start = time.perf_counter()
            self._publish_images(header, result, settings, options)
            timed(stages, "publish", start)
            self._maybe_check_calibration(header, result, options)
            want_depth = self.wanted(self._depth, options.publish_depth)
            want_points = self.wanted(self._points, options.publish_points)
            if not (want_depth or want_points):
                return {**result.timings_ms, **stages}
            self._geometry.submit((header, result, stages, options, want_depth, want_points))
        return None

    def frames_at_once(self, settings: Settings) -> int:
        return settings.options.matching_threads

    def _geometry_stage(self, job: tuple[Any, StereoResult, dict[str, float], NodeOptions, bool, bool]) -> None:
        """Second stage: depth and points2 of a published disparity, then the frame is done."""
        header, result, stages, options, want_depth, want_points = job

        def work() -> None:
            assert self.pipeline is not None and result.camera is not None
            self.pipeline.add_geometry(result, want_points=False)  # the points go straight into the cloud
            assert result.depth is not None
            if want_depth:
                start = time.perf_counter()
                self._depth.publish(array_to_image(RCLPY_TYPES, header, result.depth, "32FC1"))
                timed(stages, "publish_depth", start)
            if want_points:
                start = time.perf_counter()
                color = result.left_rect_color if result.left_rect_color is not None else result.left_rect
                rays = self.pipeline.rays_for(result.camera)
                cloud = cloud_message(header, result.depth, rays, color, options, self._cloud_buffer)
                timed(stages, "points", start)
                start = time.perf_counter()
                self._points.publish(cloud)
                timed(stages, "publish_points", start)
            self.finish_frame(stamp_to_ns(header.stamp), {**result.timings_ms, **stages})

        self.guarded(work)

    def _maybe_check_calibration(self, header: Any, result: StereoResult, options: NodeOptions) -> None:
        self._frames += 1
        if not options.calibration_check or self._frames % options.calibration_check_every_n_frames:
            return
        if not self._check_idle.is_set():
            return  # the previous check is still running: skip this one rather than queue
        self._check_idle.clear()
        stamp_ns = stamp_to_ns(header.stamp)
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

    def _publish_images(self, header: Any, result: StereoResult, settings: Settings, options: NodeOptions) -> None:
        """What the first stage publishes: rectified image, disparity, confidence."""
        assert result.camera is not None and settings.stereo is not None
        if self.wanted(self._rect, options.publish_rectified):
            self._rect.publish(array_to_image(RCLPY_TYPES, header, result.left_rect))
        if result.left_rect_color is not None and self.wanted(self._rect_color, options.publish_rectified):
            self._rect_color.publish(array_to_image(RCLPY_TYPES, header, result.left_rect_color))
        if self.wanted(self._disparity, options.publish_disparity):
            disparity = disparity_message(RCLPY_TYPES, header, result.disparity, result.camera, settings.stereo)
            self._disparity.publish(disparity)
        if result.confidence is not None and self.wanted(self._confidence, options.publish_confidence):
            self._confidence.publish(array_to_image(RCLPY_TYPES, header, result.confidence, "32FC1"))


def main(args: list[str] | None = None) -> int:
    return run_node(StereoNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
