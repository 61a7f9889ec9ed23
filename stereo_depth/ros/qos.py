"""QoS that never silently loses frames.

Measured with rclpy + Fast DDS on one machine: a best-effort subscriber receives only about half of
1 MB images from a default (reliable) publisher, because such samples exceed the 512 KB shared-memory
segment and travel as fragmented UDP; a reliable subscriber receives all of them. A reliable
subscriber, however, never matches a best-effort publisher (most camera drivers use SensorDataQoS).
So each input follows its publishers the way rosbag2 does: reliable when every publisher offers
reliable, best effort as soon as one offers only best effort, re-checked whenever a publisher appears
or goes. Outputs are reliable (as stereo_image_proc's), which both kinds of subscriber accept.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

from rclpy.event_handler import QoSMessageLostInfo, SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

OUTPUT_DEPTH = 2  # a subscriber that falls behind gets the newest outputs, not a growing queue


def output_qos() -> QoSProfile:
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=OUTPUT_DEPTH,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.VOLATILE,
    )


def input_qos(reliability: ReliabilityPolicy, depth: int) -> QoSProfile:
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=reliability,
        durability=DurabilityPolicy.VOLATILE,
    )


def choose_reliability(
    policy: str, offered: Iterable[ReliabilityPolicy], current: ReliabilityPolicy
) -> ReliabilityPolicy:
    """rosbag2's rule: reliable only if every publisher offers it; unchanged while nobody publishes."""
    if policy == "reliable":
        return ReliabilityPolicy.RELIABLE
    if policy == "best_effort":
        return ReliabilityPolicy.BEST_EFFORT
    offered = list(offered)
    if not offered:
        return current
    if all(r == ReliabilityPolicy.RELIABLE for r in offered):
        return ReliabilityPolicy.RELIABLE
    return ReliabilityPolicy.BEST_EFFORT


class AdaptiveSubscription:
    """One input subscription whose reliability follows its publishers (or a forced policy).

    Created at start-up (so `ros2 node info` lists it) as reliable, the common default for publishers;
    `recheck()` recreates it when the publishers' offer calls for the other reliability. The node calls
    `recheck()` from a timer, and the matched / incompatible-QoS events make it happen at once.
    """

    def __init__(
        self,
        node: Node,
        msg_type: Any,
        topic: str,
        callback: Callable[[Any], None],
        *,
        policy: str,
        depth: int,
        on_lost: Callable[[int], None],
    ) -> None:
        self._node = node
        self._msg_type = msg_type
        self.topic = node.resolve_topic_name(topic)
        self._callback = callback
        self._policy = policy
        self._depth = depth
        self._on_lost = on_lost
        self.recheck_requested = False
        self.reliability = choose_reliability(policy, [], ReliabilityPolicy.RELIABLE)
        self._subscription = self._create()

    def _create(self) -> Any:
        events = SubscriptionEventCallbacks(
            matched=lambda _info: self._request_recheck(),
            incompatible_qos=lambda _info: self._request_recheck(),
            message_lost=self._lost,
        )
        return self._node.create_subscription(
            self._msg_type,
            self.topic,
            self._callback,
            input_qos(self.reliability, self._depth),
            event_callbacks=events,
        )

    def _request_recheck(self) -> None:
        self.recheck_requested = True

    def _lost(self, info: QoSMessageLostInfo) -> None:
        self._on_lost(int(info.total_count_change))

    def configure(self, policy: str, depth: int) -> None:
        """New parameter values: the subscription is recreated if its QoS has to change."""
        changed = depth != self._depth
        self._policy, self._depth = policy, depth
        self.recheck(force=changed)

    def recheck(self, *, force: bool = False) -> None:
        self.recheck_requested = False
        offered = [info.qos_profile.reliability for info in self._node.get_publishers_info_by_topic(self.topic)]
        wanted = choose_reliability(self._policy, offered, self.reliability)
        if wanted == self.reliability and not force:
            return
        self._node.destroy_subscription(self._subscription)
        self.reliability = wanted
        self._subscription = self._create()
        self._node.get_logger().info(
            f"{self.topic}: subscribed {wanted.name.lower()} (publishers offer "
            f"{', '.join(sorted({r.name.lower() for r in offered})) or 'nothing yet'})"
        )
