"""Soak: stereo_node fed over DDS for as long as asked; prints memory, latency percentiles and drops.

A stereo_node process (namespace /soak) gets the artl pair, resized to --size, at --rate, each set
stamped with its publish time, so latency = receipt of its disparity - stamp on one clock. Every
--report seconds, and at the end, one line: the node's resident memory (VmRSS), latency p50 / p95 /
max of that window, frames sent / received / lost, and the node's own counts from diagnostics
(frames it replaced with newer ones because it was busy, messages the synchronizer discarded). A
window's `lost` includes the frames still in flight when it ends; the total waits for them.

At a rate the node sustains, `lost` stays 0 and memory flat after warm-up; above it, latency stays
bounded and the excess shows as `node dropped`, not as a growing queue.

    .venv/bin/python bench/soak.py --seconds 600 --rate 30 --size 640x480
    .venv/bin/python bench/soak.py --seconds 60 --rate 100 --size 320x240 -p profile:=fast

Uses ROS_DOMAIN_ID from the environment (default: a free one, locked) and LOCALHOST discovery. test/test_long_run.py
drives the same `Soak` for 300 frames.
"""

from __future__ import annotations

import argparse
import dataclasses
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from lib.domain_lock import isolate_on_this_host

from stereo_depth.machine import print_machine

REPO = Path(__file__).resolve().parents[1]
SCENE = REPO / "test" / "data" / "scenes" / "artl"
FRAME_ID = "soak_left_optical_frame"


def rss_mb(pid: int) -> float:
    """Resident memory of a process (VmRSS), MB."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    msg = f"no VmRSS for pid {pid}"
    raise RuntimeError(msg)


def percentile(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else float("nan")


@dataclasses.dataclass(frozen=True)
class Window:
    """What happened to the frames sent in one window."""

    sent: int
    received: int
    latency_ms: list[float]

    @property
    def lost(self) -> int:
        return self.sent - self.received

    def line(self) -> str:
        lat = self.latency_ms
        return (
            f"sent {self.sent:6d}  received {self.received:6d}  lost {self.lost:5d}  latency ms "
            f"p50 {percentile(lat, 50):7.1f}  p95 {percentile(lat, 95):7.1f}  max {max(lat, default=float('nan')):7.1f}"
        )


def stereo_messages(width: int, height: int) -> list[Any]:
    """Left image, left info, right image, right info of the artl pair at this size (stamps set later)."""
    from stereo_depth.formats.scenes import load_scene
    from stereo_depth.messages import array_to_image, camera_info_to_msg, make_header
    from stereo_depth.ros.types import RCLPY_TYPES

    scene = load_scene(SCENE)
    header = make_header(RCLPY_TYPES, 0, FRAME_ID)
    scale = np.diag([width / scene.left.shape[1], height / scene.left.shape[0], 1.0])
    messages = []
    for image, info in zip((scene.left, scene.right), scene.camera_infos(FRAME_ID), strict=True):
        info = dataclasses.replace(info, width=width, height=height, k=scale @ info.k, p=scale @ info.p)
        messages.append(array_to_image(RCLPY_TYPES, header, cv2.resize(image, (width, height))))
        messages.append(camera_info_to_msg(RCLPY_TYPES, header, info))
    return messages


class Soak:
    """Publishes one stereo set per tick, stamped now, and records when each disparity comes back.

    `node` must be spun by someone else (an executor thread): the disparity callback records receipts.
    """

    def __init__(self, node: Any, namespace: str, width: int, height: int) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import CameraInfo, Image
        from stereo_msgs.msg import DisparityImage

        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        topics = [("left/image_raw", Image), ("left/camera_info", CameraInfo)]
        topics += [("right/image_raw", Image), ("right/camera_info", CameraInfo)]
        self._publishers = [node.create_publisher(t, f"{namespace}/{name}", qos) for name, t in topics]
        self._messages = stereo_messages(width, height)
        self._lock = threading.Lock()
        self.sent: list[int] = []  # stamps, in publish order
        self._received: dict[int, int] = {}  # stamp -> receipt time, ns
        self.node_values: dict[str, str] = {}  # the node's last diagnostics
        self.reports = 0  # diagnostics reports received
        self._subscriptions = [
            node.create_subscription(DisparityImage, f"{namespace}/disparity", self._on_disparity, qos),
            node.create_subscription(DiagnosticArray, f"{namespace}/diagnostics", self._on_diagnostics, 10),
        ]

    def _on_disparity(self, msg: Any) -> None:
        now = time.time_ns()
        with self._lock:
            self._received[int(msg.header.stamp.sec) * 10**9 + int(msg.header.stamp.nanosec)] = now

    def _on_diagnostics(self, msg: Any) -> None:
        values = {kv.key: kv.value for kv in msg.status[0].values}
        with self._lock:
            self.node_values = values
            self.reports += 1

    def wait_matched(self, timeout_s: float = 60.0) -> None:
        deadline = time.monotonic() + timeout_s
        while any(p.get_subscription_count() < 1 for p in self._publishers) or any(
            s.get_publisher_count() < 1 for s in self._subscriptions
        ):
            if time.monotonic() > deadline:
                msg = "stereo_node did not match the soak's topics"
                raise TimeoutError(msg)
            time.sleep(0.05)
        time.sleep(0.5)  # reliable writers need the readers' first acks

    def publish(self) -> None:
        stamp = time.time_ns()
        if self.sent and stamp <= self.sent[-1]:
            stamp = self.sent[-1] + 1
        sec, nanosec = divmod(stamp, 10**9)
        for msg, publisher in zip(self._messages, self._publishers, strict=True):
            msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
            publisher.publish(msg)
        self.sent.append(stamp)

    def run(self, rate_hz: float, *, frames: int | None = None, seconds: float | None = None) -> tuple[int, int]:
        """Publish on an absolute schedule; returns the range of `sent` indices it published.

        Like a camera, it never sends a burst: when this process falls behind by more than a period
        (a busy machine), the schedule restarts from now instead of catching up with frames sent back
        to back, which would measure the publisher's stall, not the node.
        """
        first = len(self.sent)
        began = start = time.monotonic()
        period, i = 1.0 / rate_hz, 0
        while (frames is None or i < frames) and (seconds is None or time.monotonic() - began < seconds):
            delay = start + i * period - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            elif delay < -period:
                start -= delay
            self.publish()
            i += 1
        return first, len(self.sent)

    def window(self, sent_range: tuple[int, int], settle_s: float = 2.0) -> Window:
        """Outcome of the frames in `sent_range`, after waiting up to `settle_s` for the last to come back."""
        stamps = self.sent[sent_range[0] : sent_range[1]]
        deadline = time.monotonic() + settle_s
        while time.monotonic() < deadline:
            with self._lock:
                if stamps and stamps[-1] in self._received:
                    break
            time.sleep(0.02)
        with self._lock:
            latencies = [(self._received[s] - s) / 1e6 for s in stamps if s in self._received]
        return Window(len(stamps), len(latencies), latencies)

    def received_stamps(self, sent_range: tuple[int, int]) -> list[int]:
        """Stamps of the sets in `sent_range` whose disparity came back, in the order they came back."""
        wanted = set(self.sent[sent_range[0] : sent_range[1]])
        with self._lock:
            return [stamp for stamp in self._received if stamp in wanted]

    def node_count(self, key: str) -> int:
        with self._lock:
            return int(self.node_values.get(key, "0"))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=60.0, help="how long to publish")
    parser.add_argument("--rate", type=float, default=30.0, help="stereo sets per second")
    parser.add_argument("--size", default="320x240", help="WIDTHxHEIGHT of the published images")
    parser.add_argument("--report", type=float, default=10.0, help="seconds between report lines")
    parser.add_argument("-p", dest="params", action="append", default=[], help="stereo_node name:=value")
    args = parser.parse_args()
    print_machine()
    width, height = (int(v) for v in args.size.lower().split("x"))
    isolate_on_this_host()

    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    params = [a for p in args.params for a in ("-p", p)]
    command = [sys.executable, "-m", "stereo_depth.nodes.stereo_node", "--ros-args", "-r", "__ns:=/soak", *params]
    node_process = subprocess.Popen(command, stdout=subprocess.DEVNULL)
    rclpy.init()
    node = rclpy.create_node("soak")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        soak = Soak(node, "/soak", width, height)
        soak.wait_matched()
        print(f"stereo_node pid {node_process.pid}, {width}x{height} at {args.rate} Hz for {args.seconds} s")
        start, warm_rss = time.monotonic(), None
        while (elapsed := time.monotonic() - start) < args.seconds:
            window = soak.window(soak.run(args.rate, seconds=min(args.report, args.seconds - elapsed)), settle_s=0.0)
            rss = rss_mb(node_process.pid)
            warm_rss = rss if warm_rss is None else warm_rss  # the first window is the warm-up
            print(
                f"t {time.monotonic() - start:7.1f} s  rss {rss:7.1f} MB  {window.line()}  "
                f"node dropped {soak.node_count('dropped frames')}  "
                f"unmatched {soak.node_count('unmatched input messages')}",
                flush=True,
            )
        total = soak.window((0, len(soak.sent)))
        growth = rss_mb(node_process.pid) - (warm_rss or 0.0)
        print(
            f"total: {total.line()}  rss growth after the first window {growth:+.1f} MB  "
            f"node dropped {soak.node_count('dropped frames')}"
        )
    finally:
        node_process.send_signal(signal.SIGINT)
        node_process.wait(timeout=30)
        executor.shutdown()
        spinner.join(timeout=10)
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
