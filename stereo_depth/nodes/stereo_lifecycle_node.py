"""stereo_lifecycle_node: stereo_node as a managed (lifecycle) node, for nav2_lifecycle_manager and the like.

Same topics, parameters and frame path as stereo_node (it *is* a StereoNode); only when things exist
differs. Before `configure` the node has its parameters and nothing else: no matcher, no publishers,
no subscriptions. `configure` reads the calibration files and builds the matcher and the (lifecycle)
publishers; `activate` starts the workers and subscribes; `deactivate` unsubscribes and ends the
workers (a frame in progress finishes first), then the publishers fall silent; `cleanup` releases the
matcher and publishers. A transition that fails goes to errorprocessing with the reason logged;
`on_error` releases everything and returns the node to unconfigured, ready for another `configure`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from rclpy.lifecycle import LifecycleNode, LifecyclePublisher, LifecycleState, TransitionCallbackReturn
from rclpy.publisher import Publisher
from rclpy.qos import QoSProfile

from stereo_depth.nodes.stereo_node import StereoNode
from stereo_depth.ros.node_main import run_node


class StereoLifecycleNode(StereoNode, LifecycleNode):
    def __init__(self) -> None:
        super().__init__("stereo_lifecycle_node", managed=True)
        self.get_logger().info("unconfigured: parameters declared; waiting for configure")

    def create_output(self, msg_type: Any, topic: str, qos: QoSProfile | int, **options: Any) -> Publisher:
        """Publishes only while the node is active."""
        publisher: Publisher = self.create_lifecycle_publisher(msg_type, topic, qos, **options)
        return publisher

    def destroy_output(self, publisher: Publisher) -> None:
        assert isinstance(publisher, LifecyclePublisher)
        self.destroy_lifecycle_publisher(publisher)

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._transition("configure", self.configure_io, super().on_configure, state)

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        # publishers enabled first (super), so the first frame's outputs go out
        return self._transition("activate", self.activate_io, super().on_activate, state, publishers_first=True)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._transition("deactivate", self.deactivate_io, super().on_deactivate, state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._transition("cleanup", self.cleanup_io, super().on_cleanup, state)

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._transition("shutdown", self.cleanup_io, super().on_shutdown, state)

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        """A transition from `state` failed: release everything; unconfigured if that worked, else finalized."""
        try:
            self.cleanup_io()
        except Exception as exc:
            self.get_logger().error(f"error processing: releasing failed ({exc}); finalized")
            return TransitionCallbackReturn.FAILURE
        self.get_logger().warning(
            f"error processing (after a failed transition from {state.label}): inputs, workers, matcher and "
            "publishers released; unconfigured, configure again once the cause is fixed"
        )
        return super().on_error(state)

    def _transition(
        self,
        name: str,
        work: Callable[[], None],
        entities: Callable[[LifecycleState], TransitionCallbackReturn],
        state: LifecycleState,
        *,
        publishers_first: bool = False,
    ) -> TransitionCallbackReturn:
        """`work`, and the managed entities' (lifecycle publishers') callback; an exception in either is
        logged with its reason and reported as ERROR, which leads to errorprocessing (`on_error`)."""
        try:
            result = entities(state) if publishers_first else TransitionCallbackReturn.SUCCESS
            work()
            if not publishers_first:
                result = entities(state)
        except Exception as exc:
            self.get_logger().error(f"{name} failed: {exc}")
            return TransitionCallbackReturn.ERROR
        self.get_logger().info(f"{name}: done, {self._now_holds()}")
        return result

    def _now_holds(self) -> str:
        """What the node holds after a transition, for the log: the test and the user see the releases."""
        return (
            f"matcher {'built' if self.configured else 'none'}, "
            f"{len(self._outputs)} publishers, {self.subscriptions_held} subscriptions, "
            f"workers {'running' if self._worker is not None else 'stopped'}"
        )


def main(args: list[str] | None = None) -> int:
    return run_node(StereoLifecycleNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
