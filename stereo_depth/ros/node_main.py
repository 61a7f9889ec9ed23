"""The process entry of every node: rclpy's start, the spin loop, and the end on a signal.

`run_node` is each node's `main`: it sets the GIL switch interval and the large-message profile, starts
rclpy, builds the node, spins the executor its `executor` parameter names, and destroys the node and
shuts rclpy down on SIGINT / SIGTERM (ros/signals.py) before the process ends.
"""

from __future__ import annotations

import sys
from collections.abc import Callable

import rclpy
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import Executor, ExternalShutdownException
from rclpy.signals import SignalHandlerOptions

from stereo_depth.errors import StereoDepthError
from stereo_depth.ros import signals
from stereo_depth.ros.node_base import StereoIONode
from stereo_depth.ros.transport import use_large_message_profile

SIGNAL_POLL_S = 0.25  # the longest a SIGINT / SIGTERM waits for the spin to return to Python
# How long a thread running Python may keep the GIL while another waits for it (Python's default: 5 ms). The
# census core returns to Python between its kernels dozens of times a frame, and each time waits for the GIL
# while the executor or the cloud stage runs Python: at 5 ms that took its match from 50 to 180 ms beside
# one busy Python thread, at 0.5 ms to 100 ms, what sharing a core costs (docs/design/decisions.md).
GIL_SWITCH_S = 0.0005


def run_node(factory: Callable[[], StereoIONode], args: list[str] | None = None) -> int:
    """rclpy Jazzy's main(). SIGINT / SIGTERM end the spin loop below, or start-up at its next step
    (ros/signals.py), and the `finally` below stops the worker and destroys the node before the process
    ends with 0.
    A node that cannot start (bad --ros-args, --params-file or parameter value) says why in one
    line and exits with 2, rather than run with part of its configuration."""
    signals.install()
    if signals.SIGNALLED.is_set():  # during the imports
        return 0
    sys.setswitchinterval(GIL_SWITCH_S)
    profile = use_large_message_profile()
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except RuntimeError as exc:  # rcl's error (unreadable --params-file, malformed --ros-args) is one
        rclpy.logging.get_logger("stereo_depth").error(f"cannot start: {_rcl_reason(exc)}")
        return 2
    node: StereoIONode | None = None
    code = 0
    try:
        node = factory()
        if profile is not None:
            node.get_logger().info(
                f"Fast DDS: large-message profile {profile} for this process (no profile was exported); see "
                "docs/dds.md#large-messages"
            )
        executor = new_executor(node)
        executor.add_node(node)
        signals.SPINNING.set()
        try:
            # The signal handler runs between two bytecodes of this thread: the wait must return now and then,
            # also in a lifecycle state without timers of the node's own (unconfigured, inactive, finalized).
            while not signals.SIGNALLED.is_set() and executor.context.ok():
                executor.spin_once(timeout_sec=SIGNAL_POLL_S)
        finally:
            executor.remove_node(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (StereoDepthError, InvalidParameterValueException, InvalidParameterTypeException) as exc:
        rclpy.logging.get_logger("stereo_depth").error(f"cannot start: {exc}")
        code = 2
    except Exception:
        # A signal that cut numba's start-up short (signals.interruptible): its SystemExit can come out of
        # numba's imports or C calls as another exception. Still the signal's exit.
        if not signals.SIGNALLED.is_set():
            raise
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code


def new_executor(node: StereoIONode) -> Executor:
    """The executor the node's `executor` parameter names: rclpy's standard one, or its EventsExecutor, which
    waits and dispatches in C++ instead of rebuilding a wait set of every entity in Python on each wake."""
    if node.parameters.settings.options.executor == "events":
        try:
            from rclpy.experimental.events_executor import EventsExecutor
        except ImportError:  # an rclpy older than the EventsExecutor (the Jazzy wheels have it)
            node.get_logger().warning("executor:=events: this rclpy has no EventsExecutor; running the standard one")
        else:
            node.get_logger().info("executor: rclpy's EventsExecutor (executor:=events)")
            return EventsExecutor()
    return rclpy.get_global_executor()


def _rcl_reason(exc: Exception) -> str:
    """rcl's message on one line, without the C source locations it appends (", at file.c:123")."""
    return " ".join(str(exc).split(", at /")[0].split())
