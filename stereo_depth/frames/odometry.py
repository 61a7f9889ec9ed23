"""Where the rectified left camera was at a frame's stamp, from the robot's odometry (`left_in_base` set),
for the temporal filter to move its history with the camera.

The odometry gives the base's pose in the odometry frame (core/odometry.py); `left_in_base` places the left
camera as calibrated on the base, and the left camera_info's R turns that camera into the rectified one the
disparity is seen from (X_rect = R X_raw):

    camera pose = base pose @ left_in_base @ [[R^T, 0], [0, 1]]

An odometry that stops or jumps makes the filter forget its history once, at the frame where that is first
seen, and the frame reports it (`FrameOdometry.event`) for one log line; while it stays stopped the filter
goes on without odometry (its image test), until messages flow again. Frames without a pose (odometry late,
or none yet) are filtered without odometry. The state lives with the stream's other output state and is
touched in stamp order only.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from stereo_depth.core.odometry import OdometryTrack
from stereo_depth.core.params import StereoParams
from stereo_depth.core.pipeline import StereoResult
from stereo_depth.core.temporal import CameraMotion, Projection
from stereo_depth.frames.decode import StereoFrame
from stereo_depth.options import OutputOptions

NOTES = {
    "stopped": (
        "odometry stopped (no message within odom_wait_seconds of a frame): the temporal filter forgot its "
        "history and filters without odometry until messages come again"
    ),
    "jumped": (
        "odometry jumped (a pose change its twist cannot explain: a reset or a relocalisation): the temporal "
        "filter forgot its history"
    ),
}


def odometry_note(event: str, topic: str) -> str:
    """The one line a node or `process` gives when the odometry on `topic` stops or jumps."""
    return f"{topic}: {NOTES[event]}"


class FrameOdometry(NamedTuple):
    """What the odometry says about one frame: the camera's motion for the temporal filter (None: filter
    without odometry) and the event first seen at this frame ("stopped" / "jumped"; None: none)."""

    motion: CameraMotion | None = None
    event: str | None = None


class OdometryState:
    """Per stream, between frames: the previous frame's stamp (the start of the span checked for jumps) and
    why the last frame's odometry was not used (an event is reported, and forgets, once)."""

    def __init__(self) -> None:
        self.previous_ns: int | None = None
        self.reason: str | None = None

    def reset(self) -> None:
        self.previous_ns, self.reason = None, None

    def frame(
        self,
        track: OdometryTrack,
        frame: StereoFrame,
        result: StereoResult,
        params: StereoParams,
        output: OutputOptions,
    ) -> FrameOdometry:
        """This frame's odometry; call once per frame in stamp order, before the temporal filter. Off
        (temporal_filter false, left_in_base unset, no calibration): nothing, so the filter runs as without."""
        if not params.temporal_filter:
            self.reset()
            return FrameOdometry()
        if not output.left_in_base.is_set or result.camera is None:
            return FrameOdometry()
        lookup = track.lookup(frame.stamp_ns, self.previous_ns, output.odom_wait_seconds)
        event = lookup.reason if lookup.forget and lookup.reason != self.reason else None
        self.previous_ns, self.reason = frame.stamp_ns, lookup.reason
        pose = None
        if lookup.pose is not None:
            pose = lookup.pose @ camera_in_base(output, frame.camera.left.r)
        return FrameOdometry(CameraMotion(pose, Projection.of(result.camera), forget=event is not None), event)


def camera_in_base(output: OutputOptions, rectification: np.ndarray) -> np.ndarray:
    """4x4: the rectified left camera in the base frame, from the calibrated one (`left_in_base`) and the left
    camera_info's R (the frame's raw calibration: R = I for images that came rectified with a P-only
    camera_info)."""
    pose = output.left_in_base
    rectified_in_raw = np.eye(4)
    rectified_in_raw[:3, :3] = np.asarray(rectification, np.float64).T
    return pose.matrix() @ rectified_in_raw
