"""rectify_node: one camera's image + camera_info in, image_rect out (image_proc's contract).

Uses the same maps and the same "identity?" decision as the stereo pipeline, so a split chain sees
exactly the pixels stereo_node matches. R is applied even when every distortion coefficient is zero.
"""

from __future__ import annotations

import time

import cv2
import numpy as np
from sensor_msgs.msg import CameraInfo, Image

from stereo_depth.core.camera import CameraInfo as Calibration
from stereo_depth.core.camera import build_rectification_maps, check_camera_info, needs_rectification
from stereo_depth.errors import CalibrationError
from stereo_depth.frames import decode_image, named_errors
from stereo_depth.messages import array_to_image, camera_info_from_msg
from stereo_depth.options import INPUT_OPTIONS, Settings
from stereo_depth.ros.node_base import FrameJob, StereoIONode, timed
from stereo_depth.ros.node_main import run_node
from stereo_depth.ros.types import RCLPY_TYPES


class RectifyNode(StereoIONode):
    INPUTS = (("image", Image), ("camera_info", CameraInfo))
    CALIBRATIONS = ((1, 0),)
    OUTPUTS = (("image_rect", Image),)
    OPTIONS = (*INPUT_OPTIONS, "interpolation")

    def __init__(self) -> None:
        super().__init__("rectify_node")

    def open_outputs(self) -> None:
        self._maps: tuple[Calibration, tuple[np.ndarray, np.ndarray] | None] | None = None
        self._rect = self.declared_output("image_rect")

    def process(self, job: FrameJob, settings: Settings) -> dict[str, float]:
        image_msg, info_msg = job.messages
        start = time.perf_counter()
        with named_errors(self.topics[0]):
            image = decode_image(image_msg, settings.output.max_image_pixels)
        with named_errors(self.topics[1]):
            info = camera_info_from_msg(info_msg)
        maps = self._maps_for(info, image.shape)
        stages: dict[str, float] = {}
        timed(stages, "decode", start)
        start = time.perf_counter()
        rectified = image if maps is None else cv2.remap(image, *maps, settings.options.interpolation)
        timed(stages, "rectify", start)
        start = time.perf_counter()
        self._rect.publish(array_to_image(RCLPY_TYPES, image_msg.header, rectified))
        self.published("image_rect", job.received_s)
        timed(stages, "publish", start)
        return stages

    def _maps_for(self, info: Calibration, shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray] | None:
        """Cached maps for this calibration; None when rectifying would not move a pixel.

        The size is checked first: maps for an absurd camera_info size would exhaust memory."""
        if shape[:2] != (info.height, info.width):
            msg = (
                f"{self.topics[0]}: image is {shape[1]}x{shape[0]} but {self.topics[1]} says "
                f"{info.width}x{info.height}; the calibration does not belong to this camera mode"
            )
            raise CalibrationError(msg)
        if self._maps is None or self._maps[0] != info:
            check_camera_info(info, self.topics[1])
            self._maps = (info, build_rectification_maps(info) if needs_rectification(info) else None)
        return self._maps[1]


def main(args: list[str] | None = None) -> int:
    return run_node(RectifyNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
