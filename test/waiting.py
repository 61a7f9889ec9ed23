"""Waiting in tests: every wait has a deadline, and a wait that runs out names what it waited for.

No ROS here, so the tests of offline tools use it without rclpy. Deadlines are generous (this runs on
2-core machines) and nothing asserts a duration.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

TIMEOUT_S = 20.0


def wait_until(condition: Callable[..., Any], what: str, timeout: float = TIMEOUT_S, poll: float = 0.02) -> Any:
    """`condition()`'s first truthy value; TimeoutError naming `what` when none came within `timeout` s."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(poll)
    msg = f"timed out after {timeout} s waiting for {what}"
    raise TimeoutError(msg)
