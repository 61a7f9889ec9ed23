"""What points2 costs per frame in each layout a navigation or mapping user picks: bytes on the wire,
build time (frames.geometry_outputs, as stereo_node's second stage calls it) and publish time
(rclpy's publish() to one subscriber over real DDS on this machine), for the organized cloud
(stereo_image_proc's layout, the baseline), organized ones of every 2nd and 4th pixel
(points_decimation), the dense one (organized_cloud false) and voxel-thinned ones. The frame: the first
raw EuRoC pair of test/data/euroc (752x480), matched with the default profile.

    flock /tmp/stereo_depth_cpu.lock .venv/bin/python bench/cloud_outputs.py [--repeat 30] [--markdown]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import threading
import time
from pathlib import Path

import cv2
import rclpy
from lib.domain_lock import isolate_on_this_host
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2

from stereo_depth.core.params import make_params
from stereo_depth.core.pipeline import StereoPipeline
from stereo_depth.formats.euroc import stereo_camera_infos
from stereo_depth.frames import OutputState, StereoFrame, geometry_outputs, match_frame, result_geometry
from stereo_depth.messages import make_header
from stereo_depth.options import OutputOptions
from stereo_depth.ros.types import RCLPY_TYPES

sys.path.insert(0, str(Path(__file__).parent))
from lib.table import parse_bench_arguments, table_header, table_row, times

EUROC = Path(__file__).resolve().parents[1] / "test" / "data" / "euroc"
LAYOUTS = {
    "organized (default)": OutputOptions(),
    "organized, decimation 2": OutputOptions(points_decimation=2),
    "organized, decimation 4": OutputOptions(points_decimation=4),
    "dense": OutputOptions(organized_cloud=False),
    "dense, voxel 0.05 m": OutputOptions(organized_cloud=False, cloud_voxel_size=0.05),
    "dense, voxel 0.2 m": OutputOptions(organized_cloud=False, cloud_voxel_size=0.2),
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=30)
    args = parse_bench_arguments(parser)
    name = sorted((EUROC / "left").glob("*.png"))[0].name
    left, right = (cv2.imread(str(EUROC / side / name), cv2.IMREAD_GRAYSCALE) for side in ("left", "right"))
    assert left is not None and right is not None, f"cannot read the EuRoC pair {name}"
    pipeline = StereoPipeline(make_params())
    camera = pipeline.camera_for(*stereo_camera_infos(EUROC / "cam0_sensor.yaml", EUROC / "cam1_sensor.yaml"))
    header = make_header(RCLPY_TYPES, 1, "cam0")
    frame = StereoFrame(1, header, left, right, camera, rectified=False)

    isolate_on_this_host()
    rclpy.init()
    node = rclpy.create_node("cloud_outputs_bench")
    qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
    publisher = node.create_publisher(PointCloud2, "bench_points2", qos)
    received: list[object] = []
    node.create_subscription(PointCloud2, "bench_points2", received.append, qos)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    while publisher.get_subscription_count() < 1:
        time.sleep(0.05)

    if args.markdown:
        print(table_header(("points2 layout", "points", "MB", "build + publish ms", "vs organized")))
    else:
        print(
            f"{'points2 layout':25s}{'points':>9s}{'MB':>8s}{'build ms':>10s}{'publish ms':>12s}"
            f"{'total/organized':>17s}"
        )
    baseline = None
    for label, options in LAYOUTS.items():
        state = OutputState()
        build, publish = [], []
        cloud = None
        for _ in range(args.repeat + 2):
            result = match_frame(pipeline, frame)
            start = time.perf_counter()
            geometry = result_geometry(pipeline, frame, result)
            cloud = geometry_outputs(RCLPY_TYPES, header, geometry, options, ("points2",), state)["points2"]
            built = time.perf_counter()
            publisher.publish(cloud)
            build.append((built - start) * 1000.0)
            publish.append((time.perf_counter() - built) * 1000.0)
        assert cloud is not None
        build_ms, publish_ms = statistics.median(build[2:]), statistics.median(publish[2:])
        total = build_ms + publish_ms
        baseline = baseline or total
        points = cloud.width * cloud.height
        if args.markdown:
            cost = f"{build_ms:.1f} + {publish_ms:.1f}"
            print(table_row((label, points, f"{len(cloud.data) / 1e6:.2f}", cost, times(total / baseline))), flush=True)
            continue
        print(
            f"{label:25s}{points:9d}{len(cloud.data) / 1e6:8.2f}{build_ms:10.2f}{publish_ms:12.2f}"
            f"{total / baseline:17.2f}",
            flush=True,
        )
    executor.shutdown()
    spinner.join()
    node.destroy_node()
    rclpy.try_shutdown()


if __name__ == "__main__":
    main()
