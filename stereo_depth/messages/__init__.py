"""Message <-> array converters by field names, for rclpy messages and rosbags messages alike.

This package imports neither ROS nor rosbags: callers hand in a `MessageTypes` (the classes of their
flavour) and get messages of that flavour back. Every image encoding, row padding, byte order and
point-cloud layout detail lives here and nowhere else, one module per kind of message: images,
transports (compressed, compressedDepth), camera_info, disparity, clouds, odometry; `common` holds what they
share.
The geometry they carry (depth, points, voxel thinning) is the core's (core/geometry.py).
"""

from stereo_depth.messages.camera_info import camera_info_from_msg, camera_info_to_msg, same_calibration
from stereo_depth.messages.clouds import FLOAT32, cloud_layout, cloud_to_arrays, depth_to_cloud, pack_rgb
from stereo_depth.messages.common import (
    DATA_MARK,
    DEFAULT_MAX_PIXELS,
    MessageBuffer,
    MessageTypes,
    SerializedMessage,
    check_pixel_count,
    in_serialized_bytes,
    make_header,
    stamp_to_ns,
)
from stereo_depth.messages.disparity import disparity_from_msg, disparity_to_msg
from stereo_depth.messages.images import (
    CAMERA_ENCODINGS,
    ENCODINGS,
    array_to_image,
    encoding_for,
    image_to_array,
    image_to_pipeline,
)
from stereo_depth.messages.odometry import ODOMETRY_TYPE, odometry_from_msg
from stereo_depth.messages.transports import (
    COMPRESSED_DEPTH_FORMATS,
    COMPRESSED_FORMATS,
    RVL_FALLBACK_NOTE,
    array_to_compressed,
    compressed_depth_codec,
    compressed_format,
    compressed_to_pipeline,
    depth_to_compressed_depth,
)

__all__ = [
    "CAMERA_ENCODINGS",
    "COMPRESSED_DEPTH_FORMATS",
    "COMPRESSED_FORMATS",
    "DATA_MARK",
    "DEFAULT_MAX_PIXELS",
    "ENCODINGS",
    "FLOAT32",
    "ODOMETRY_TYPE",
    "RVL_FALLBACK_NOTE",
    "MessageBuffer",
    "MessageTypes",
    "SerializedMessage",
    "array_to_compressed",
    "array_to_image",
    "camera_info_from_msg",
    "camera_info_to_msg",
    "check_pixel_count",
    "cloud_layout",
    "cloud_to_arrays",
    "compressed_depth_codec",
    "compressed_format",
    "compressed_to_pipeline",
    "depth_to_cloud",
    "depth_to_compressed_depth",
    "disparity_from_msg",
    "disparity_to_msg",
    "encoding_for",
    "image_to_array",
    "image_to_pipeline",
    "in_serialized_bytes",
    "make_header",
    "odometry_from_msg",
    "pack_rgb",
    "same_calibration",
    "stamp_to_ns",
]
