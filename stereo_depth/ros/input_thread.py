"""The node's input subscriptions, waited on and taken on a thread of their own instead of in rclpy's executor.

rclpy's standard executor rebuilds its wait set in Python from every entity of the node each time it wakes,
holding the GIL, and takes one message per wake: a stereo frame's four inputs reach DDS within a fraction of a
millisecond, but the last of them reached its callback 1.2-2 ms later (bench/e2e_dds.py --timeline). This
thread keeps a wait set of the inputs alone (their subscriptions and their lost-message events) and takes
every message that is ready at each wake, then those that came in meanwhile (a frame's right image and
camera_info arrive while it takes the left ones: refilling the wait set and waiting again cost ~0.1 ms a
time on the 2-core Xeon), so the set goes to the worker as soon as its last input is in.

The subscriptions and their events are created in `NotInExecutor`, a callback group that rclpy's executor
never runs, so it leaves them out of its wait set: Fast DDS wakes one wait set per subscription (its listener
holds one condition), and with both waiting on it this thread missed wake-ups and lost messages. The executor
keeps the timers, the parameter services and everything else. rclpy's EventsExecutor (`executor:=events`)
dispatches in C++ and keeps the inputs itself.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from contextlib import ExitStack
from typing import Any, cast

from rclpy.callback_groups import CallbackGroup
from rclpy.event_handler import EventHandler
from rclpy.exceptions import InvalidHandle
from rclpy.guard_condition import GuardCondition
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.subscription import Subscription

WAKE_S = 0.25  # the longest the thread waits without looking at its flags
DRAIN_PASSES = 4  # after a wake, passes over every input for what came in meanwhile, before waiting again


class NotInExecutor(CallbackGroup):
    """A callback group whose entities rclpy's executors never run (nor wait for)."""

    def can_execute(self, entity: Any) -> bool:
        return False

    def beginning_execution(self, entity: Any) -> bool:
        return False

    def ending_execution(self, entity: Any) -> None:
        return None


class InputThread:
    """Waits on `subscriptions()` (read again after each `changed()`) and calls each one's callback with
    (message, DDS sample info), as rclpy's executor calls a two-argument callback, and each lost-message
    event's callback; `report` gets any exception a callback raises, and the thread goes on."""

    def __init__(
        self, node: Node, subscriptions: Callable[[], list[Subscription]], report: Callable[[Exception], None]
    ) -> None:
        self._node, self._subscriptions, self._report = node, subscriptions, report
        self._wake = GuardCondition(None, None, context=node.context)
        # the subscriptions last read, their lost-message events and the wait set sized for them (rebuilt
        # only when `subscriptions()` returns others; refilled at each wake, as rcl's wait empties it)
        self._entities: tuple[tuple[Subscription, ...], list[EventHandler], Any] | None = None
        self._running = True
        self._thread = threading.Thread(target=self._run, name="inputs", daemon=True)
        self._thread.start()

    def changed(self) -> None:
        """The subscriptions were replaced: wait on the new ones (and let the old ones be destroyed)."""
        self._wake.trigger()

    def stop(self) -> None:
        self._running = False
        self._wake.trigger()
        self._thread.join()
        self._entities = None  # the wait set too, before the guard condition it holds
        self._wake.destroy()

    def _run(self) -> None:
        context = self._node.context
        while self._running and context.ok():
            try:
                self._wait_and_take(context)
            except InvalidHandle:
                continue  # a subscription being replaced (AdaptiveSubscription.recheck): read them again
            except Exception as exc:  # a callback's error, or rcl's as the context shuts down
                if self._running and context.ok():
                    self._report(exc)

    def _current(self, context: Any) -> tuple[tuple[Subscription, ...], list[EventHandler], Any]:
        subscriptions = tuple(self._subscriptions())
        if self._entities is None or self._entities[0] != subscriptions:
            events = [
                handler
                for subscription in subscriptions
                for handler in cast("list[EventHandler]", subscription.event_handlers)  # rclpy annotates one
            ]
            wait_set = _rclpy.WaitSet(len(subscriptions), 1, 0, 0, 0, len(events), context.handle)
            self._entities = (subscriptions, events, wait_set)
        return self._entities

    def _wait_and_take(self, context: Any) -> None:
        subscriptions, events, wait_set = self._current(context)
        with ExitStack() as in_use:  # none of them is destroyed while waited on
            for subscription in subscriptions:
                in_use.enter_context(subscription.handle)
            for handler in events:
                in_use.enter_context(handler)
            in_use.enter_context(self._wake.handle)
            wait_set.clear_entities()
            for subscription in subscriptions:
                wait_set.add_subscription(subscription.handle)
            for handler in events:
                handler.add_to_wait_set(wait_set)
            wait_set.add_guard_condition(self._wake.handle)
            wait_set.wait(int(WAKE_S * 1e9))
            ready = wait_set.get_ready_entities("subscription")
            for handler in events:
                if handler.is_ready(wait_set):
                    taken = handler.take_data()
                    if taken:
                        handler.callback(taken)
            for subscription in subscriptions:
                if subscription.handle.pointer in ready:
                    self._take_all(subscription)
            for _ in range(DRAIN_PASSES):  # a take that finds nothing costs ~1 us; a wait, a hundred
                took = [self._take_all(subscription) for subscription in subscriptions]  # each one, every pass
                if not any(took):
                    break

    def _take_all(self, subscription: Subscription) -> bool:
        """Take and hand on every message waiting on `subscription`; whether there was any."""
        took = False
        while self._running:
            taken = subscription.handle.take_message(subscription.msg_type, subscription.raw)
            if taken is None:
                return took
            took = True
            subscription.callback(*taken)
        return took
