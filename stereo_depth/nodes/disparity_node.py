"""disparity_node: rectified pair in, stereo_msgs/DisparityImage out (stereo_image_proc's contract),
with stereo_node's temporal filter (`temporal_filter`, the same FrameStream; moved by the robot's odometry
with `left_in_base` set)."""

from __future__ import annotations

from stereo_msgs.msg import DisparityImage

from stereo_depth.options import DRIVER_FIX_OPTIONS, INPUT_OPTIONS, ODOMETRY_OPTIONS
from stereo_depth.ros.matching_node import MatchingNode, stereo_inputs
from stereo_depth.ros.node_main import run_node
from stereo_depth.sync import STEREO_CALIBRATIONS


class DisparityNode(MatchingNode):
    INPUTS = stereo_inputs("image_rect")
    CALIBRATIONS = tuple(STEREO_CALIBRATIONS.items())
    OPTIONS = (*INPUT_OPTIONS, *DRIVER_FIX_OPTIONS, "cpu_threads", *ODOMETRY_OPTIONS)
    RECTIFIED = True
    OUTPUTS = (("disparity", DisparityImage),)  # always built, listened to or not

    def __init__(self) -> None:
        super().__init__("disparity_node")


def main(args: list[str] | None = None) -> int:
    return run_node(DisparityNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
