"""stereo_node: raw stereo pair in, rectified pair, disparity, depth and points2 out, in one process.

The node most users run: no intermediate topics, so no extra serialization of full-size images.
Topics and parameters are stereo_image_proc's (docs/parameters.md lists them); `profile:=stereo_image_proc`
gives its defaults.

Two worker stages form a pipeline (ros/matching_node.py): the first rectifies, matches and publishes the
disparity (and the rectified images and confidence); the second turns that disparity into depth and points2
and publishes them, while the first already matches the next frame. With `matching_threads:=2` the first
stage matches two frames at once, for matchers that leave cores idle.
"""

from __future__ import annotations

from typing import Any

from sensor_msgs.msg import CameraInfo, CompressedImage, Image, PointCloud2
from stereo_msgs.msg import DisparityImage

from stereo_depth.options import (
    CAMERA_OPTIONS,
    CLOUD_OPTIONS,
    DRIVER_FIX_OPTIONS,
    INPUT_OPTIONS,
    ODOMETRY_OPTIONS,
    REGISTRATION_OPTIONS,
)
from stereo_depth.ros.matching_node import MatchingNode, stereo_inputs
from stereo_depth.ros.node_main import run_node
from stereo_depth.sync import STEREO_CALIBRATIONS

OUTPUT_TYPES = {
    "left/image_rect": Image,
    "left/image_rect_color": Image,
    "right/image_rect": Image,
    "right/image_rect_color": Image,
    "disparity": DisparityImage,
    "confidence": Image,
    "depth": Image,
    "depth/camera_info": CameraInfo,
    "depth/compressedDepth": CompressedImage,
    "points2": PointCloud2,
    "points2_clearing": PointCloud2,
    # with rgb_in_left set only: depth registered to the colour camera (frames/registered.py)
    "depth_registered/image_rect": Image,
    "depth_registered/camera_info": CameraInfo,
    "rgb/image_rect_color": Image,
    "depth_registered/points": PointCloud2,
}
# the publish_* parameter that switches each output on or off
SWITCHES = {
    "left/image_rect": "publish_rectified",
    "left/image_rect_color": "publish_rectified",
    "right/image_rect": "publish_rectified",
    "right/image_rect_color": "publish_rectified",
    "disparity": "publish_disparity",
    "confidence": "publish_confidence",
    "depth": "publish_depth",
    "depth/camera_info": "publish_depth",
    "depth/compressedDepth": "publish_depth",  # built only while someone subscribes, as image_transport's
    "points2": "publish_points",
    "points2_clearing": "publish_points_clearing",
}


class StereoNode(MatchingNode):
    INPUTS = stereo_inputs("image_raw")
    CALIBRATIONS = tuple(STEREO_CALIBRATIONS.items())
    IMAGE_INPUTS = (0, 2)
    CAMERA_INFO_FILES = ((1, "left_camera_info_url"), (3, "right_camera_info_url"))
    OPTIONS = (
        *INPUT_OPTIONS,
        *CAMERA_OPTIONS,
        *DRIVER_FIX_OPTIONS,
        *CLOUD_OPTIONS,
        "depth_encoding",
        "clearing_max_depth",
        "near_points",
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
        *REGISTRATION_OPTIONS,
        *ODOMETRY_OPTIONS,
    )
    MAX_FRAMES_AT_ONCE = 4
    OUTPUTS = tuple(OUTPUT_TYPES.items())
    OUTPUT_SWITCHES = SWITCHES

    def __init__(self, name: str = "stereo_node", **kwargs: Any) -> None:
        super().__init__(name, **kwargs)


def main(args: list[str] | None = None) -> int:
    return run_node(StereoNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
