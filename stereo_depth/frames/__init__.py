"""The frame layer, ROS-free: one frame from its input messages to its output messages, the one path of
the live nodes and `process`.

- `stream`: `FrameStream`, what the nodes and `process` call; it returns image messages, a cloud job
  and whether the calibration changed;
- `decode`: a `StereoSet` (the synchronizer's inputs, by name) -> `StereoFrame`, sizes checked and every
  error naming the input it is about;
- `outputs`: the stages after matching (temporal filter, depth limits, mask) and the messages they give.

Messages of either flavour (rclpy or rosbags) go in, messages of the caller's `MessageTypes` come out
(see stereo_depth.messages).
"""

from stereo_depth.frames.decode import (
    INPUT_NAMES,
    InputNames,
    StereoFrame,
    camera_fixes,
    decode_frame,
    decode_image,
    match_frame,
    named_errors,
)
from stereo_depth.frames.outputs import (
    CLOUDS,
    DEFAULT_OUTPUTS,
    GEOMETRY_OUTPUTS,
    IMAGE_OUTPUTS,
    OUTPUTS,
    Geometry,
    OutputState,
    depth_pixels,
    disparity_message,
    filtered_disparity,
    geometry_outputs,
    image_outputs,
    result_geometry,
    valid_region,
)
from stereo_depth.frames.stream import CloudJob, CloudOutputs, DisparityOutputs, FrameOutputs, FrameStream, Matched

__all__ = [
    "CLOUDS",
    "DEFAULT_OUTPUTS",
    "GEOMETRY_OUTPUTS",
    "IMAGE_OUTPUTS",
    "INPUT_NAMES",
    "OUTPUTS",
    "CloudJob",
    "CloudOutputs",
    "DisparityOutputs",
    "FrameOutputs",
    "FrameStream",
    "Geometry",
    "InputNames",
    "Matched",
    "OutputState",
    "StereoFrame",
    "camera_fixes",
    "decode_frame",
    "decode_image",
    "depth_pixels",
    "disparity_message",
    "filtered_disparity",
    "geometry_outputs",
    "image_outputs",
    "match_frame",
    "named_errors",
    "result_geometry",
    "valid_region",
]
