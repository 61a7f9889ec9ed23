"""QoS that never silently loses frames.

Measured with rclpy + Fast DDS on one machine: a best-effort subscriber receives only about half of
1 MB images from a default (reliable) publisher, because such samples exceed the 512 KB shared-memory
segment and travel as fragmented UDP; a reliable subscriber receives all of them. A reliable
subscriber, however, never matches a best-effort publisher (most camera drivers use SensorDataQoS).
So each input follows its publishers the way rosbag2 does: reliable when every publisher offers
reliable, best effort as soon as one offers only best effort, re-checked whenever a publisher appears
or goes. Outputs are reliable (as stereo_image_proc's), which both kinds of subscriber accept.

Every input and output also takes rclpy's per-topic QoS overrides (`qos_overrides.<topic>.publisher|
subscription.history|depth|reliability`, read-only parameters declared with the endpoint, so `ros2
param list` shows them): what the user states wins over the rules above, for that endpoint only.
"""

from __future__ import annotations

import difflib
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from typing import Any

from rclpy.callback_groups import CallbackGroup
from rclpy.event_handler import QoSMessageLostInfo, SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSCompatibility,
    QoSPolicyKind,
    QoSProfile,
    ReliabilityPolicy,
    qos_check_compatible,
    qos_policy_name_from_kind,
)
from rclpy.qos_overriding_options import InvalidQosOverridesError, QoSOverridingOptions
from rclpy.subscription import Subscription
from rclpy.topic_endpoint_info import TopicEndpointInfo

from stereo_depth.errors import ParameterError

OUTPUT_DEPTH = 2  # a subscriber that falls behind gets the newest outputs, not a growing queue
QOS_OVERRIDES = "qos_overrides."
OVERRIDABLE = QoSOverridingOptions.with_default_policies().policy_kinds  # history, depth, reliability


def output_qos() -> QoSProfile:
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=OUTPUT_DEPTH,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.VOLATILE,
    )


def type_name(msg_type: Any) -> str:
    """A message class's ROS type name as the graph reports it, e.g. sensor_msgs/msg/Image."""
    return f"{msg_type.__module__.split('.')[0]}/msg/{msg_type.__name__}"


def broken_policy(offered: QoSProfile, requested: QoSProfile) -> QoSPolicyKind:
    """The policy that keeps a subscription asking for `requested` from a publisher offering `offered`,
    given that `qos_check_compatible` found the two incompatible."""
    if requested.reliability == ReliabilityPolicy.RELIABLE and offered.reliability == ReliabilityPolicy.BEST_EFFORT:
        return QoSPolicyKind.RELIABILITY
    if requested.durability == DurabilityPolicy.TRANSIENT_LOCAL and offered.durability == DurabilityPolicy.VOLATILE:
        return QoSPolicyKind.DURABILITY
    wanted, given = requested.deadline.nanoseconds, offered.deadline.nanoseconds  # 0: none (infinite)
    if wanted > 0 and not 0 < given <= wanted:
        return QoSPolicyKind.DEADLINE
    return QoSPolicyKind.LIVELINESS


class SubscriberWatch:
    """rclpy's incompatible-QoS warning for one output, found by looking at the graph, not by an event handler.

    rclpy gives each publisher two event handlers, and its standard executor rebuilds its wait set from
    every handler of the node in Python each time it wakes, holding the GIL, several times a frame
    (docs/design/decisions.md). So outputs carry none: the node calls `check` from a timer, which looks
    at the topic's subscriptions when their count moved (or `everything`), and warns once about each
    that asks for QoS the output does not offer. A subscriber of another type is its own node's to report.
    """

    def __init__(self, node: Node, publisher: Publisher) -> None:
        self._node, self._publisher = node, publisher
        self._count = -1  # the topic's subscription count at the last look; -1: not looked yet
        self._warned: set[bytes] = set()  # endpoint GIDs warned about

    def check(self, *, everything: bool = False) -> None:
        topic = self._publisher.topic_name
        count = self._node.count_subscribers(topic)
        if count == self._count and not everything:
            return
        self._count = count
        offered = self._offered(topic)
        seen = set()
        for info in self._node.get_subscriptions_info_by_topic(topic):
            gid = bytes(info.endpoint_gid)
            seen.add(gid)
            if gid in self._warned or qos_check_compatible(offered, info.qos_profile)[0] != QoSCompatibility.ERROR:
                continue
            self._warned.add(gid)
            policy = qos_policy_name_from_kind(broken_policy(offered, info.qos_profile))
            self._node.get_logger().warning(
                f"New subscription discovered on topic '{topic}', requesting incompatible QoS. No messages will be "
                f"sent to it. Last incompatible policy: {policy}"
            )
        self._warned &= seen

    def _offered(self, topic: str) -> QoSProfile:
        """The output's QoS as the graph reports it, the way it reports the subscriptions': the profile the
        publisher was created with leaves the deadline and the lifespan unset (0), which rclpy's check
        finds incompatible with the graph's "infinite" of every plain subscriber (a false warning)."""
        name, namespace = self._node.get_name(), self._node.get_namespace()
        for info in self._node.get_publishers_info_by_topic(topic):
            if info.node_name == name and info.node_namespace == namespace:
                reported: QoSProfile = info.qos_profile
                return reported
        return self._publisher.qos_profile  # not in the graph yet


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
    """rosbag2's rule: reliable only if every publisher offers it; unchanged while nobody publishes.
    Any policy other than "auto" (input_reliability, or a reliability override) is taken as it is."""
    if policy != "auto":
        return ReliabilityPolicy[policy.upper()]
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
    `check()` from a timer, as `SubscriberWatch`'s, which rechecks when the topic's publisher count moved
    (a publisher came or went) or `everything`. That is polled, not evented: each event handler costs
    every wake of rclpy's executor, and a count of the topic's publishers catches the matched and the
    incompatible ones alike. `recheck()` also warns, once, about each publisher of another type, which never matches and
    has no say in the reliability. The subscription carries one handler, for lost messages (counted).
    The policies the user overrode (`qos_overrides.<topic>.subscription.*`) are applied to every
    recreation; a reliability override replaces the adaptive rule for this topic.
    """

    def __init__(
        self,
        node: Node,
        msg_type: Any,
        topic: str,
        callback: Callable[..., None],  # (message, its DDS sample info): rclpy passes both to a 2-argument one
        *,
        policy: str,
        depth: int,
        on_lost: Callable[[int], None],
        callback_group: CallbackGroup | None = None,  # input_thread.NotInExecutor: taken on the input thread
        on_replaced: Callable[[], None] = lambda: None,  # after `recheck` recreated the subscription
        raw: bool = False,  # the callback gets the message's CDR bytes
    ) -> None:
        self._node = node
        self._raw = raw
        self._group, self._on_replaced = callback_group, on_replaced
        self._msg_type = msg_type
        self._type_name = type_name(msg_type)
        self._wrong_types: set[bytes] = set()  # GIDs of publishers of another type, warned about
        self.topic = node.resolve_topic_name(topic)
        self._callback = callback
        self._policy = policy
        self._depth = depth
        self._on_lost = on_lost
        self._publishers = -1  # the topic's publisher count at the last look; -1: not looked yet
        self._overridden = given_overrides(node, self.topic, "subscription")
        self.reliability = choose_reliability(policy, [], ReliabilityPolicy.RELIABLE)
        # The first subscription of this topic declares its override parameters (and rclpy checks the values
        # given); a later one (re-activated lifecycle node) must not take their start values for its own.
        declared = node.has_parameter(f"{QOS_OVERRIDES}{self.topic}.subscription.reliability")
        self._subscription = self._create(() if declared else OVERRIDABLE)
        self.reliability = self._subscription.qos_profile.reliability

    def _effective(self, policy: str) -> str:
        """input_reliability, unless this topic's reliability is overridden."""
        if QoSPolicyKind.RELIABILITY in self._overridden:
            return str(self._overridden[QoSPolicyKind.RELIABILITY])
        return policy

    def _create(self, overridable: Iterable[QoSPolicyKind] = ()) -> Subscription:
        events = SubscriptionEventCallbacks(message_lost=self._lost, use_default_callbacks=False)
        with override_errors():
            return self._node.create_subscription(
                self._msg_type,
                self.topic,
                self._callback,
                input_qos(self.reliability, self._depth),
                event_callbacks=events,
                qos_overriding_options=QoSOverridingOptions([*overridable, *self._overridden]),
                callback_group=self._group,
                raw=self._raw,
            )

    @property
    def subscription(self) -> Subscription:
        return self._subscription

    def check(self, *, everything: bool = False) -> None:
        """`recheck` when the topic's publisher count moved since the last look, or `everything`."""
        count = self._node.count_publishers(self.topic)
        changed, self._publishers = count != self._publishers, count
        if changed or everything:
            self.recheck()

    def _lost(self, info: QoSMessageLostInfo) -> None:
        self._on_lost(int(info.total_count_change))

    def destroy(self) -> None:
        self._node.destroy_subscription(self._subscription)

    def configure(self, policy: str, depth: int) -> None:
        """New parameter values: the subscription is recreated if its QoS has to change."""
        changed = depth != self._depth
        self._policy, self._depth = policy, depth
        self.recheck(force=changed)

    def recheck(self, *, force: bool = False) -> None:
        publishers = self._node.get_publishers_info_by_topic(self.topic)
        self._warn_wrong_types(publishers)
        offered = [info.qos_profile.reliability for info in publishers if info.topic_type == self._type_name]
        wanted = choose_reliability(self._effective(self._policy), offered, self.reliability)
        if wanted == self.reliability and not force:
            return
        self._node.destroy_subscription(self._subscription)
        self.reliability = wanted
        self._subscription = self._create()
        self._on_replaced()
        self._node.get_logger().info(
            f"{self.topic}: subscribed {wanted.name.lower()} (publishers offer "
            f"{', '.join(sorted({r.name.lower() for r in offered})) or 'nothing yet'})"
        )

    def _warn_wrong_types(self, publishers: list[TopicEndpointInfo]) -> None:
        wrong = {bytes(info.endpoint_gid): info.topic_type for info in publishers if info.topic_type != self._type_name}
        for gid in wrong.keys() - self._wrong_types:
            self._node.get_logger().warning(
                f"Incompatible type on topic '{self.topic}': a publisher sends {wrong[gid]}, this node takes "
                f"{self._type_name}; no messages will be received from it."
            )
        self._wrong_types = set(wrong)


def given_overrides(node: Node, topic: str, entity: str) -> dict[QoSPolicyKind, Any]:
    """The policies of `topic`'s publisher or subscription that -p / --params-file override, with the
    values given (rclpy keeps them in `_parameter_overrides` until the endpoint declares them)."""
    prefix = f"{QOS_OVERRIDES}{topic}.{entity}."
    given = getattr(node, "_parameter_overrides", {})
    return {
        kind: given[prefix + kind.name.lower()].value for kind in OVERRIDABLE if prefix + kind.name.lower() in given
    }


@contextmanager
def override_errors() -> Iterator[None]:
    """rclpy's errors for an override value it cannot apply, as our ParameterError (one line, exit 2)."""
    try:
        yield
    except (InvalidQosOverridesError, RuntimeError) as exc:
        if isinstance(exc, RuntimeError) and "QoS override" not in str(exc):
            raise
        raise ParameterError(str(exc)) from exc


def unused_overrides_line(node: Node) -> str | None:
    """One line naming the given qos_overrides that match no endpoint of this node (a misspelt topic
    would otherwise be ignored without a word), each with the closest declared one; None if all apply."""
    declared = sorted(node.list_parameters([QOS_OVERRIDES.rstrip(".")], 0).names)
    unused = sorted(
        name
        for name in getattr(node, "_parameter_overrides", {})
        if name.startswith(QOS_OVERRIDES) and not node.has_parameter(name)
    )
    if not unused:
        return None
    hints = []
    for name in unused:
        close = difflib.get_close_matches(name, declared, n=1)
        hints.append(f"'{name}' (did you mean '{close[0]}'?)" if close else f"'{name}'")
    return "qos_overrides for no topic of this node, ignored: " + "; ".join(hints)
