"""The ROS nodes, one console script each (`ros2 run stereo_depth <name>`); stereo_lifecycle_node is managed.

Ctrl-C or SIGTERM must end a node with exit code 0 and no traceback, whenever it arrives. Importing
OpenCV and rclpy takes a second or two, so the handler is installed here, before any of that, and
stays in charge after `rclpy.init` (which is told to install none): raising SystemExit between two
bytecodes of the main thread unwinds through `run_node`'s cleanup without racing rclpy's C code,
which rclpy's own SIGTERM handler does when it shuts the context down from another thread.
"""

from __future__ import annotations

import signal
from types import FrameType


def _exit_quietly(signum: int, frame: FrameType | None) -> None:
    del frame
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_IGN)  # a second signal must not interrupt the cleanup
    raise SystemExit(0)


for _sig in (signal.SIGINT, signal.SIGTERM):
    signal.signal(_sig, _exit_quietly)
