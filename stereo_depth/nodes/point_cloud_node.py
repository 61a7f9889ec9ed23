"""point_cloud_node: DisparityImage + rectified left image in, organized points2 out.

Depth is computed from the message's offset-adjusted disparity with the same arithmetic as
stereo_node, so the split chain and the all-in-one node give the same cloud bit for bit.
"""

from __future__ import annotations

import time
from typing import Any

from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from stereo_msgs.msg import DisparityImage

from stereo_depth.core.geometry import disparity_to_depth
from stereo_depth.core.pipeline import StereoPipeline
from stereo_depth.errors import ImageError
from stereo_depth.frames import Geometry, InputNames, OutputState, geometry_outputs
from stereo_depth.messages import disparity_from_msg
from stereo_depth.options import CLOUD_OPTIONS, INPUT_OPTIONS, Settings
from stereo_depth.ros.serialized_publish import publish
from stereo_depth.ros.stereo_io import StereoIONode, run_node, timed
from stereo_depth.ros.types import RCLPY_SERIALIZED
from stereo_depth.sync import StereoSet


class PointCloudNode(StereoIONode):
    INPUTS = (
        ("left/image_rect_color", Image),
        ("left/camera_info", CameraInfo),
        ("right/camera_info", CameraInfo),
        ("disparity", DisparityImage),
    )
    CALIBRATIONS = ((1, 0), (2, 3))  # the disparity carries the left image's stamp
    OUTPUTS = (("points2", PointCloud2),)
    OPTIONS = (*INPUT_OPTIONS, *CLOUD_OPTIONS, "baseline")

    def __init__(self) -> None:
        super().__init__("point_cloud_node")

    def open_outputs(self) -> None:
        self.pipeline = StereoPipeline()  # only its calibration and ray caches are used here
        self._points = self.declared_output("points2")
        self._state = OutputState()  # its cloud buffer is reused frame to frame: publish() serializes first

    def process(self, stamp_ns: int, messages: tuple[Any, ...], settings: Settings) -> dict[str, float]:
        assert self.pipeline is not None
        image_msg, left_info, right_info, disparity_msg = messages
        start = time.perf_counter()
        inputs = StereoSet(stamp_ns, image_msg, left_info, None, right_info)  # a disparity, no right image
        names = InputNames(self.topics[0], self.topics[1], "", self.topics[2])
        frame = self.read_frame(inputs, settings, rectified=True, names=names)
        camera = frame.camera
        disparity = self.read_input(3, disparity_from_msg, disparity_msg)
        if disparity.shape != (camera.height, camera.width):
            msg = (
                f"{self.topics[3]}: {disparity.shape[1]}x{disparity.shape[0]} but camera_info says "
                f"{camera.width}x{camera.height}; remap the topics of one camera together"
            )
            raise ImageError(msg)
        if camera.no_depth_reason is not None:
            self.problems.warn_once(camera.no_depth_reason)
            return {}
        stages: dict[str, float] = {}
        timed(stages, "decode", start)
        if not self._state.cloud_rate.due(frame.stamp_ns, settings.output.points_max_rate):
            return stages
        start = time.perf_counter()
        depth = disparity_to_depth(disparity, camera, offset_adjusted=True)
        geometry = Geometry(depth, camera, self.pipeline.rays_for(camera), frame.left, camera)
        output = settings.output
        cloud = geometry_outputs(RCLPY_SERIALIZED, frame.header, geometry, output, ("points2",), self._state)
        timed(stages, "points", start)
        start = time.perf_counter()
        publish(self._points, cloud["points2"])
        self.published("points2")
        timed(stages, "publish", start)
        return stages


def main(args: list[str] | None = None) -> int:
    return run_node(PointCloudNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
