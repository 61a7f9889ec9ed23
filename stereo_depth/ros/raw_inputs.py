"""Input images and camera_infos taken as their CDR bytes and read with rosbags' generated reader.

rclpy's take of a sensor_msgs message deserializes it into a C struct, then builds the Python message
field by field (every setter checks its value; d, k, r and p become numpy arrays). On the input thread that
is the critical path: a frame's set goes to the matcher only once its four messages are taken, and the
frame after 30 ms of idle cores runs that code at a fraction of its warm speed. Taken raw (rclpy copies
the bytes) and read by rosbags (a view of the image bytes, no copy), a camera_info took 0.013 ms of the
thread's CPU in the node instead of 0.13 ms, an image 0.07-0.13 instead of 0.14-0.28 ms (each take timed
by hand); with the input thread's draining, the last input went from DDS to its callback in 0.57-0.60
against 0.76-0.85 ms in runs taken in turn with the commit before (2-core Xeon, BM VGA 30 Hz;
bench/e2e_dds.py --timeline --cases bm_vga_30_16b, 2026-12-06).

The messages are rosbags' dataclasses, which the rest of the package reads as it reads a bag's, with
their header replaced by an rclpy Header: the nodes' outputs carry their input's header in rclpy messages.
CompressedImage and DisparityImage inputs stay rclpy's own.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from builtin_interfaces.msg import Time
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Header

from stereo_depth.errors import MessageError

RAW_TYPES = {Image: "sensor_msgs/msg/Image", CameraInfo: "sensor_msgs/msg/CameraInfo"}


def raw_reader(msg_type: Any) -> Callable[[bytes], Any] | None:
    """What turns a `msg_type` input's CDR bytes into a message (MessageError where they are not one);
    None: subscribe to it as rclpy's."""
    name = RAW_TYPES.get(msg_type)
    if name is None:
        return None
    store = get_typestore(Stores.ROS2_JAZZY)  # the messages of the rclpy this runs on (ros/ does not use bag/)

    def read(raw: bytes) -> Any:
        try:
            message: Any = store.deserialize_cdr(raw, name)
        except SerdeError as exc:
            text = f"{len(raw)} bytes that are not a {name} ({exc}); the message is skipped"
            raise MessageError(text) from exc
        header = message.header
        stamp = Time(sec=header.stamp.sec, nanosec=header.stamp.nanosec)
        message.header = Header(stamp=stamp, frame_id=header.frame_id)
        return message

    return read
