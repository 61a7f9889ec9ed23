"""point_cloud_node: DisparityImage + rectified left image in, organized points2 out.

Depth is computed from the message's offset-adjusted disparity with the same arithmetic as
stereo_node, so the split chain and the all-in-one node give the same cloud bit for bit.
"""

from __future__ import annotations

import time

from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from stereo_msgs.msg import DisparityImage

from stereo_depth.options import CLOUD_OPTIONS, INPUT_OPTIONS, Settings
from stereo_depth.ros.node_base import FrameJob, timed
from stereo_depth.ros.node_main import run_node
from stereo_depth.ros.stream_node import StreamNode
from stereo_depth.sync import StereoSet


class PointCloudNode(StreamNode):
    INPUTS = (
        ("left/image_rect_color", Image),
        ("left/camera_info", CameraInfo),
        ("right/camera_info", CameraInfo),
        ("disparity", DisparityImage),
    )
    CALIBRATIONS = ((1, 0), (2, 3))  # the disparity carries the left image's stamp
    OPTIONS = (*INPUT_OPTIONS, *CLOUD_OPTIONS, "baseline")
    RECTIFIED = True
    OUTPUTS = (("points2", PointCloud2),)
    NAMED_INPUTS = (0, 1, None, 2)  # the stream's calibration and ray caches and cloud buffer are used here

    def __init__(self) -> None:
        super().__init__("point_cloud_node")

    def process(self, job: FrameJob, settings: Settings) -> dict[str, float]:
        image_msg, left_info, right_info, disparity_msg = job.messages
        start = time.perf_counter()
        self.stream.use(None, settings.output)
        inputs = StereoSet(job.stamp_ns, image_msg, left_info, None, right_info)  # a disparity, no right image
        out = self.stream.disparity_cloud(inputs, disparity_msg, self.topics[3])
        if out.calibration_changed:
            self.note_calibration(out.frame.camera)
        if out.frame.camera.no_depth_reason is not None:
            self.problems.warn_once(out.frame.camera.no_depth_reason)
            return {}
        stages: dict[str, float] = {}
        timed(stages, "decode", start)
        if out.cloud is None:  # not due (points_max_rate)
            return stages
        cloud = out.cloud.run()
        self.publish_outputs(cloud.messages, stages, job.received_s)
        return {**cloud.stage_ms, **stages}


def main(args: list[str] | None = None) -> int:
    return run_node(PointCloudNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
