"""A node's odometry input (left_in_base set): `odom` (nav_msgs/Odometry, relative to the node's namespace,
remappable), subscribed from activation to deactivation, each message added to the stream's odometry track
for the temporal filter (frames/odometry.py).

A frame's odometry normally arrives after the frame: the worker waits for the message at or after the
frame's stamp (`wait_for_odometry`) up to `odom_wait_seconds`, then takes the frame without it. The
subscription follows its publishers' reliability as the camera inputs do (ros/qos.py), and diagnostics
report the topic as an input: its rate, and its silence while the cameras publish.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial

from nav_msgs.msg import Odometry
from rclpy.node import Node

from stereo_depth.core.odometry import OdometryTrack
from stereo_depth.messages import odometry_from_msg
from stereo_depth.options import NodeOptions
from stereo_depth.ros.diagnostics import NodeDiagnostics
from stereo_depth.ros.qos import AdaptiveSubscription

ODOM_TOPIC = "odom"
ODOM_DEPTH = 50  # messages queued: half a second of 100 Hz odometry while the executor is busy


class OdometryInput:
    """Resolved at configure; subscribed at `open` (activate), released at `close`."""

    def __init__(self, node: Node) -> None:
        self._node = node
        self.topic = node.resolve_topic_name(ODOM_TOPIC)
        self._subscription: AdaptiveSubscription | None = None

    def open(
        self,
        options: NodeOptions,
        track: OdometryTrack,
        diagnostics: NodeDiagnostics,
        report_bug: Callable[[Exception], None],
    ) -> None:
        """Subscribe; the track starts empty (what came before a pause says nothing about now)."""
        track.clear()

        def received(message: Odometry) -> None:
            try:
                sample = odometry_from_msg(message)
                track.add(sample)
                diagnostics.input_received(self.topic, sample.stamp_ns)
            except Exception as exc:
                report_bug(exc)

        self._subscription = AdaptiveSubscription(
            self._node,
            Odometry,
            self.topic,
            received,
            policy=options.reliability,
            depth=ODOM_DEPTH,
            on_lost=partial(diagnostics.input_lost, self.topic),
        )

    def close(self) -> None:
        if self._subscription is not None:
            self._subscription.destroy()
            self._subscription = None

    @property
    def subscriptions(self) -> list[AdaptiveSubscription]:
        return [self._subscription] if self._subscription is not None else []

    def options_changed(self, new: NodeOptions) -> None:
        if self._subscription is not None:
            self._subscription.configure(new.reliability, ODOM_DEPTH)


def wait_for_odometry(track: OdometryTrack, stamp_ns: int, wait_s: float) -> None:
    """Wait up to `wait_s` for the odometry message at or after a frame's stamp. Not at all when none came
    within `wait_s` before the stamp either: the odometry has stopped (or not started), and a message
    that comes now would not change that frame's answer (core/odometry.py: a gap longer than the wait)."""
    if track.wait_past(stamp_ns - round(wait_s * 1e9), 0.0):
        track.wait_past(stamp_ns, wait_s)
