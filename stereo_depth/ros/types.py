"""The rclpy message classes, as the `MessageTypes` records that `stereo_depth.messages` builds with."""

from __future__ import annotations

import dataclasses

from builtin_interfaces.msg import Time
from rclpy.serialization import serialize_message
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, PointCloud2, PointField, RegionOfInterest
from std_msgs.msg import Header
from stereo_msgs.msg import DisparityImage

from stereo_depth.messages import MessageTypes

RCLPY_TYPES = MessageTypes(
    Header=Header,
    Time=Time,
    Image=Image,
    CompressedImage=CompressedImage,
    CameraInfo=CameraInfo,
    RegionOfInterest=RegionOfInterest,
    DisparityImage=DisparityImage,
    PointCloud2=PointCloud2,
    PointField=PointField,
)
# what the nodes publish: the disparity and organized clouds as their serialized bytes, built in place and
# published with the GIL released (stereo_depth.ros.serialized_publish); other messages as RCLPY_TYPES
RCLPY_SERIALIZED = dataclasses.replace(RCLPY_TYPES, serialize=serialize_message)
