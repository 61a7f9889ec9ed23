"""What stereo_lifecycle_node holds in each lifecycle state and what each transition costs: the node's
resident memory and thread count (from /proc) after each transition, and the time from the
change_state request to its answer, for one cycle (configure, activate, deactivate, activate,
deactivate, cleanup, shutdown), against a plain stereo_node started beside it. No frames are sent.

    ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST ROS_DOMAIN_ID=62 .venv/bin/python bench/lifecycle_states.py
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import rclpy
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState

CYCLE = (
    ("configure", Transition.TRANSITION_CONFIGURE),
    ("activate", Transition.TRANSITION_ACTIVATE),
    ("deactivate", Transition.TRANSITION_DEACTIVATE),
    ("activate", Transition.TRANSITION_ACTIVATE),
    ("deactivate", Transition.TRANSITION_DEACTIVATE),
    ("cleanup", Transition.TRANSITION_CLEANUP),
    ("shutdown", Transition.TRANSITION_UNCONFIGURED_SHUTDOWN),
)
SETTLE_S = 1.0  # let threads end and the allocator settle before /proc is read


def holdings(pid: int) -> str:
    status = dict(line.split(":", 1) for line in Path(f"/proc/{pid}/status").read_text().splitlines())
    rss_mb = int(status["VmRSS"].split()[0]) / 1024
    return f"RSS {rss_mb:7.1f} MB, {int(status['Threads']):3d} threads"


def start(module: str) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        [sys.executable, "-m", f"stereo_depth.nodes.{module}", "--ros-args", "-r", "__ns:=/bench_lifecycle"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )


def main() -> None:
    rclpy.init()
    node = rclpy.create_node("bench_lifecycle")
    managed, plain = start("stereo_lifecycle_node"), start("stereo_node")
    try:
        client = node.create_client(ChangeState, "/bench_lifecycle/stereo_lifecycle_node/change_state")
        assert client.wait_for_service(timeout_sec=60.0), "stereo_lifecycle_node offers no change_state"
        time.sleep(SETTLE_S)
        print(f"{'unconfigured (start)':<22} {'':>12} {holdings(managed.pid)}")
        for label, transition in CYCLE:
            begin = time.perf_counter()
            future = client.call_async(ChangeState.Request(transition=Transition(id=transition)))
            rclpy.spin_until_future_complete(node, future, timeout_sec=60.0)
            took_ms = (time.perf_counter() - begin) * 1000
            assert future.done() and future.result().success, f"{label} failed"
            time.sleep(SETTLE_S)
            print(f"{label:<22} {took_ms:9.1f} ms {holdings(managed.pid)}")
        print(f"{'plain stereo_node':<22} {'':>12} {holdings(plain.pid)}")
    finally:
        for process in (managed, plain):
            process.terminate()
            process.wait(timeout=60)
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
