"""disparity_node: rectified pair in, stereo_msgs/DisparityImage out (stereo_image_proc's contract)."""

from __future__ import annotations

import time
from typing import Any

from sensor_msgs.msg import CameraInfo, Image
from stereo_msgs.msg import DisparityImage

from stereo_depth.outputs import disparity_message
from stereo_depth.ros.parameters import INPUT_OPTIONS, Settings
from stereo_depth.ros.stereo_io import StereoIONode, run_node, timed
from stereo_depth.ros.types import RCLPY_TYPES


class DisparityNode(StereoIONode):
    INPUTS = (
        ("left/image_rect", Image),
        ("left/camera_info", CameraInfo),
        ("right/image_rect", Image),
        ("right/camera_info", CameraInfo),
    )
    CALIBRATIONS = ((1, 0), (3, 2))
    OPTIONS = INPUT_OPTIONS
    WITH_STEREO = True

    def __init__(self) -> None:
        super().__init__("disparity_node")
        self._disparity = self.output(DisparityImage, "disparity")

    def process(self, messages: tuple[Any, ...], settings: Settings) -> dict[str, float]:
        assert self.pipeline is not None and settings.stereo is not None
        left_msg = messages[0]
        start = time.perf_counter()
        left, right, camera = self.read_stereo_pair(messages, settings.options)
        stages: dict[str, float] = {}
        timed(stages, "decode", start)
        result = self.match_pair(left, right, camera, rectified=True)
        start = time.perf_counter()
        assert result.camera is not None  # the processed-size camera with downsample_output: processed
        message = disparity_message(RCLPY_TYPES, left_msg.header, result.disparity, result.camera, settings.stereo)
        self._disparity.publish(message)
        timed(stages, "publish", start)
        return {**result.timings_ms, **stages}


def main(args: list[str] | None = None) -> int:
    return run_node(DisparityNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
