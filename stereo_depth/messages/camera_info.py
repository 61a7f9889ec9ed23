"""sensor_msgs/CameraInfo <-> the core's CameraInfo."""

from __future__ import annotations

from typing import Any

import numpy as np

from stereo_depth.core.camera import CameraInfo
from stereo_depth.messages.common import MessageTypes, _floats


def camera_info_from_msg(msg: Any) -> CameraInfo:
    return CameraInfo.from_values(
        msg.width, msg.height, msg.k, msg.d, msg.r, msg.p, msg.distortion_model, msg.header.frame_id
    )


def same_calibration(a: Any, b: Any) -> bool:
    """Whether two CameraInfo messages (rclpy or rosbags) describe one calibration, stamps aside: the
    synchronizer lets the last camera_info stand in for a lost one only while this holds."""
    scalars = ("width", "height", "distortion_model", "binning_x", "binning_y")
    if any(getattr(a, name) != getattr(b, name) for name in scalars) or a.header.frame_id != b.header.frame_id:
        return False
    return all(np.array_equal(np.asarray(getattr(a, name)), np.asarray(getattr(b, name))) for name in "dkrp")


def camera_info_to_msg(types: MessageTypes, header: Any, info: CameraInfo) -> Any:
    roi = types.RegionOfInterest(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    return types.CameraInfo(
        header=header,
        height=info.height,
        width=info.width,
        distortion_model=info.distortion_model,
        d=_floats(types, info.d),
        k=np.asarray(info.k, np.float64).ravel(),
        r=np.asarray(info.r, np.float64).ravel(),
        p=np.asarray(info.p, np.float64).ravel(),
        binning_x=0,
        binning_y=0,
        roi=roi,
    )
