"""What publishing a VGA points2 costs the node's other threads: rclpy's publish() of the message against
the cloud built in its CDR bytes and published with the GIL released (stereo_depth/ros/serialized_publish.py).

At 30 Hz, the organized cloud of a 640x480 frame (the anchor's frames, BM; 32-byte and 16-byte points) is
built and published on a thread of its own to a subscriber in another process (raw, as a monitor takes
it), the two ways in turn frame by frame, while the main thread matches the next frame (stereo_node's
first stage, as when the node is behind and the two stages overlap) and a third Python thread ticks
every 0.2 ms (the node's executor needs the GIL between its calls too). Prints the medians of: the time
to build the cloud, the time in publish, the longest gap between two ticks during the publish (about
the tick when the GIL is free, the whole publish when it is held) and the time of the match meanwhile.

    .venv/bin/python bench/serialized_publish.py [--frames 60]
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from stereo_depth.core.params import make_params
from stereo_depth.core.pipeline import StereoPipeline
from stereo_depth.frames import StereoFrame, match_frame, result_geometry
from stereo_depth.messages import MessageBuffer, depth_to_cloud, make_header
from stereo_depth.ros.transport import use_large_message_profile

sys.path.insert(0, str(Path(__file__).parent))
from anchor_frames import FRAME_ID, camera_infos, frames
from domain_lock import isolate_on_this_host
from markdown_table import parse_bench_arguments, table_header, table_row, times

TOPIC = "serialized_publish_bench/points2"
WAYS = ("rclpy publish()", "serialized, GIL released")
TICK_S = 0.0002


def subscriber(expected: int) -> None:
    """The other process: takes the clouds raw until `expected` came or none came for 10 s, prints how many."""
    import rclpy
    from sensor_msgs.msg import PointCloud2

    rclpy.init()
    node = rclpy.create_node("serialized_publish_subscriber")
    count = [0]
    node.create_subscription(PointCloud2, TOPIC, lambda _: count.__setitem__(0, count[0] + 1), 10, raw=True)
    seen, last = 0, time.monotonic()
    while count[0] < expected and time.monotonic() - last < 10.0:
        rclpy.spin_once(node, timeout_sec=0.1)
        if count[0] > seen:
            seen, last = count[0], time.monotonic()
    print(count[0], flush=True)


class Ticker:
    """A Python thread that ticks every TICK_S; `longest_gap()` since `reset()`."""

    def __init__(self) -> None:
        self._gaps: list[float] = []
        self._stop = False
        self._last = time.perf_counter()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        self._last = time.perf_counter()
        while not self._stop:
            time.sleep(TICK_S)
            now = time.perf_counter()
            self._gaps.append(now - self._last)
            self._last = now

    def reset(self) -> None:
        self._gaps = []

    def longest_gap(self) -> float:
        """Up to now: a tick still waiting for the GIL counts too."""
        return max([*self._gaps, time.perf_counter() - self._last])

    def stop(self) -> None:
        self._stop = True
        self._thread.join()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=60, help="frames per way and point size")
    parser.add_argument("--subscriber", type=int, help=argparse.SUPPRESS)  # the other process: clouds to take
    if "--subscriber" in sys.argv:
        subscriber(parser.parse_args().subscriber)
        return
    args = parse_bench_arguments(parser)
    use_large_message_profile()  # as our nodes do: a 10 MB cloud in shared memory
    isolate_on_this_host()
    import rclpy
    from sensor_msgs.msg import PointCloud2

    from stereo_depth.ros.serialized_publish import publish
    from stereo_depth.ros.types import RCLPY_SERIALIZED, RCLPY_TYPES

    types = {WAYS[0]: RCLPY_TYPES, WAYS[1]: RCLPY_SERIALIZED}
    pipeline = StereoPipeline(make_params("stereo_image_proc"))
    camera = pipeline.camera_for(*camera_infos(640, 480))
    left, right = next(iter(frames(640, 480, 1)))
    frame = StereoFrame(0, make_header(RCLPY_TYPES, 0, FRAME_ID), left, right, camera, rectified=False)
    geometry = result_geometry(pipeline, frame, match_frame(pipeline, frame))
    depth, rays, color = geometry.depth, geometry.rays, geometry.image
    clouds = args.frames * 2 * len(WAYS)
    other = subprocess.Popen([sys.executable, __file__, "--subscriber", str(clouds)], stdout=subprocess.PIPE, text=True)
    rclpy.init()
    node = rclpy.create_node("serialized_publish_bench")
    publisher = node.create_publisher(PointCloud2, TOPIC, 10)
    while publisher.get_subscription_count() == 0:  # a cloud sent during discovery is lost
        time.sleep(0.05)
    time.sleep(1.0)
    buffers = {(way, padding): MessageBuffer() for way in WAYS for padding in (False, True)}
    figures: dict[tuple[str, bool], list[tuple[float, ...]]] = {key: [] for key in buffers}
    ticker = Ticker()

    def cloud_stage(i: int, way: str, avoid_padding: bool) -> tuple[float, float, float]:
        """Build and publish one cloud on the cloud thread, as the node's second stage: build, publish
        and the longest stall of the ticking thread during the publish, in s."""
        start = time.perf_counter()
        header = make_header(types[way], i + 1, FRAME_ID)
        cloud: Any = depth_to_cloud(types[way], header, depth, rays, color, avoid_padding, buffers[way, avoid_padding])
        built = time.perf_counter()
        ticker.reset()
        publish(publisher, cloud)
        return built - start, time.perf_counter() - built, ticker.longest_gap()

    second_stage = ThreadPoolExecutor(max_workers=1)
    for i in range(args.frames * len(buffers)):
        key = list(buffers)[i % len(buffers)]
        start = time.perf_counter()
        cloud = second_stage.submit(cloud_stage, i, *key)
        match_frame(pipeline, frame)  # the next frame's match meanwhile, as in a node that is behind
        match_s = time.perf_counter() - start
        figures[key].append((*cloud.result(), match_s))
        time.sleep(max(0.0, 1 / 30 - (time.perf_counter() - start)))
    ticker.stop()
    second_stage.shutdown()
    node.destroy_node()
    rclpy.shutdown()
    received = other.communicate(timeout=60)[0].strip() or "?"
    took = f"the other process took {received} of {clouds} clouds"
    print(f"640x480 organized points2 and BM, {args.frames} frames per row, 30 Hz; {took}")
    columns = ["points", "way", "build ms", "publish ms", "longest stall of another thread ms", "match meanwhile ms"]
    columns += ["publish vs publish()", "match vs publish()'s"]
    print(table_header(columns) if args.markdown else "  ".join(columns))
    for avoid_padding in (False, True):
        medians = {
            way: [statistics.median(f[k] for f in figures[way, avoid_padding]) * 1e3 for k in range(4)] for way in WAYS
        }
        for way in WAYS:
            build, publish_ms, stall, match_ms = medians[way]
            cells = [
                "16 B" if avoid_padding else "32 B",
                way,
                *(f"{v:.2f}" for v in (build, publish_ms, stall, match_ms)),
            ]
            cells += [times(publish_ms / medians[WAYS[0]][1]), times(match_ms / medians[WAYS[0]][3])]
            print(table_row(cells) if args.markdown else "  ".join(cells))


if __name__ == "__main__":
    main()
