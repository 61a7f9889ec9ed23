"""disparity_node: rectified pair in, stereo_msgs/DisparityImage out (stereo_image_proc's contract),
with stereo_node's temporal filter (`temporal_filter`).

The filter is the same `filter_over_time` stereo_node runs, so the split chain filters as it does."""

from __future__ import annotations

import time
from typing import Any

from sensor_msgs.msg import CameraInfo, Image
from stereo_msgs.msg import DisparityImage

from stereo_depth.core.temporal import TemporalFilter
from stereo_depth.frames import filter_over_time, image_outputs
from stereo_depth.messages import MessageBuffer
from stereo_depth.options import DRIVER_FIX_OPTIONS, INPUT_OPTIONS, TEMPORAL_OPTIONS, Settings
from stereo_depth.ros.serialized_publish import publish
from stereo_depth.ros.stereo_io import StereoIONode, run_node, timed
from stereo_depth.ros.types import RCLPY_SERIALIZED
from stereo_depth.sync import STEREO_CALIBRATIONS, StereoSet


class DisparityNode(StereoIONode):
    INPUTS = (
        ("left/image_rect", Image),
        ("left/camera_info", CameraInfo),
        ("right/image_rect", Image),
        ("right/camera_info", CameraInfo),
    )
    CALIBRATIONS = tuple(STEREO_CALIBRATIONS.items())
    OUTPUTS = (("disparity", DisparityImage),)
    OPTIONS = (*INPUT_OPTIONS, *DRIVER_FIX_OPTIONS, *TEMPORAL_OPTIONS, "cpu_threads")
    WITH_STEREO = True

    def __init__(self) -> None:
        super().__init__("disparity_node")

    def open_outputs(self) -> None:
        self._disparity = self.declared_output("disparity")
        self._temporal = TemporalFilter()  # frames come one at a time, in the order they were matched
        self._buffer = MessageBuffer()  # the disparity's bytes, reused: each message is published before the next

    def process(self, stamp_ns: int, messages: tuple[Any, ...], settings: Settings) -> dict[str, float]:
        assert settings.stereo is not None
        start = time.perf_counter()
        frame = self.read_frame(StereoSet.paired(stamp_ns, messages), settings, rectified=True)
        stages: dict[str, float] = {}
        timed(stages, "decode", start)
        result = self.match(frame)
        filter_over_time(self._temporal, frame, result, settings.output)
        start = time.perf_counter()
        for message in image_outputs(
            RCLPY_SERIALIZED, frame.header, result, settings.stereo, ("disparity",), self._buffer
        ).values():
            publish(self._disparity, message)
            self.published("disparity")
        timed(stages, "publish", start)
        return {**result.timings_ms, **stages}


def main(args: list[str] | None = None) -> int:
    return run_node(DisparityNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
