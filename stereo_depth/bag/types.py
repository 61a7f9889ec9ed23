"""Message classes of the rosbags typestore (ROS 2 Jazzy), as the `MessageTypes` that stereo_depth.messages takes.

Bags are read and written without an rclpy install: rosbags generates Jazzy's message classes as
dataclasses, and their CDR bytes are the ones a live Jazzy publisher sends.
"""

from __future__ import annotations

from functools import cache
from typing import Any

from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from stereo_depth.messages import MessageTypes

ROS_DISTRO_STORE = Stores.ROS2_JAZZY


@cache
def typestore() -> Typestore:
    return get_typestore(ROS_DISTRO_STORE)


@cache
def rosbags_types() -> MessageTypes:
    types = typestore().types
    return MessageTypes(
        Header=types["std_msgs/msg/Header"],
        Time=types["builtin_interfaces/msg/Time"],
        Image=types["sensor_msgs/msg/Image"],
        CompressedImage=types["sensor_msgs/msg/CompressedImage"],
        CameraInfo=types["sensor_msgs/msg/CameraInfo"],
        RegionOfInterest=types["sensor_msgs/msg/RegionOfInterest"],
        DisparityImage=types["stereo_msgs/msg/DisparityImage"],
        PointCloud2=types["sensor_msgs/msg/PointCloud2"],
        PointField=types["sensor_msgs/msg/PointField"],
    )


def serialize(message: Any) -> memoryview:
    return typestore().serialize_cdr(message, message.__msgtype__)


def deserialize(raw: bytes | memoryview, msgtype: str) -> Any:
    return typestore().deserialize_cdr(raw, msgtype)
