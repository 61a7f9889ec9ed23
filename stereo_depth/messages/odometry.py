"""nav_msgs/Odometry -> `OdometrySample`, for rclpy and rosbags messages alike (the same field names)."""

from __future__ import annotations

from typing import Any

from stereo_depth.core.odometry import OdometrySample
from stereo_depth.messages.common import stamp_to_ns

ODOMETRY_TYPE = "nav_msgs/msg/Odometry"


def odometry_from_msg(msg: Any) -> OdometrySample:
    """The base's pose in the odometry frame at the header's stamp (pose.pose) and its twist in the base
    frame (twist.twist); the covariances are not used."""
    pose, twist = msg.pose.pose, msg.twist.twist
    p, q, v, w = pose.position, pose.orientation, twist.linear, twist.angular
    return OdometrySample(
        stamp_to_ns(msg.header.stamp),
        (float(p.x), float(p.y), float(p.z)),
        (float(q.x), float(q.y), float(q.z), float(q.w)),
        (float(v.x), float(v.y), float(v.z)),
        (float(w.x), float(w.y), float(w.z)),
    )
