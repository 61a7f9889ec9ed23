"""What depth/compressedDepth saves and costs, and what points2_clearing costs, per VGA-sized frame.

The frames: the six raw EuRoC pairs of test/data/euroc (752x480), matched with the default profile.
Per depth encoding and codec: bytes of the raw depth image against the compressedDepth message's data,
and the encode time (messages.depth_to_compressed_depth, as frames.geometry_outputs calls it); then
the time to build points2_clearing (max_depth 5 m). Medians over frames x repeats; the CPU is printed.
Then with rvl asked for, per frame from all invalid to a typical EuRoC one: the codec sent (PNG where
image_transport's decoder would refuse the RVL stream: more than 5 pixels a byte) and its bytes.

    flock /tmp/stereo_depth_cpu.lock .venv/bin/python bench/compressed_depth.py [--repeat 10]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from stereo_depth.core.params import make_params
from stereo_depth.core.pipeline import StereoPipeline
from stereo_depth.formats.euroc import stereo_camera_infos
from stereo_depth.frames import (
    OutputState,
    StereoFrame,
    depth_pixels,
    geometry_outputs,
    result_geometry,
)
from stereo_depth.messages import compressed_depth_codec, depth_to_compressed_depth, make_header
from stereo_depth.options import OutputOptions
from stereo_depth.ros.types import RCLPY_TYPES

sys.path.insert(0, str(Path(__file__).parent))
from lib.table import parse_bench_arguments, table_header

EUROC = Path(__file__).resolve().parents[1] / "test" / "data" / "euroc"


def median_ms(work: Callable[[], Any], repeat: int) -> tuple[float, float, Any]:
    """(wall ms, this thread's CPU ms, result): on a shared machine the CPU time is the steadier figure."""
    walls, cpus, result = [], [], None
    for _ in range(repeat):
        start, start_cpu = time.perf_counter(), time.thread_time()
        result = work()
        cpus.append((time.thread_time() - start_cpu) * 1000.0)
        walls.append((time.perf_counter() - start) * 1000.0)
    return statistics.median(walls), statistics.median(cpus), result


def mostly_invalid(shape: tuple[int, int]) -> dict[str, np.ndarray]:
    """The depth RVL packs tightest: a floor (one depth a row) valid only in its nearest rows, as with
    max_depth in a large room, a dark scene or a lens cap."""
    height, width = shape
    floor = np.repeat(np.linspace(6.0, 1.0, height, dtype=np.float32)[:, None], width, axis=1)
    frames = {}
    for invalid in (100, 95, 80, 60):
        frame = floor.copy()
        frame[: height * invalid // 100] = np.nan
        frames["all invalid" if invalid == 100 else f"{invalid} % invalid, smooth"] = frame
    return frames


def print_codec_per_frame(typical: np.ndarray, header: Any) -> None:
    print(table_header(("frame (rvl asked for)", "depth", "codec sent", "bytes", "pixels per byte")))
    for name, depth in {**mostly_invalid(typical.shape), "EuRoC, typical": typical}.items():
        for encoding in ("16UC1", "32FC1"):
            message = depth_to_compressed_depth(
                RCLPY_TYPES, header, depth_pixels(depth, encoding), encoding, codec="rvl"
            )
            size = len(message.data)
            print(f"| {name} | {encoding} | {compressed_depth_codec(message)} | {size:,} | {depth.size / size:.1f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=10)
    args = parse_bench_arguments(parser)
    pipeline = StereoPipeline(make_params())
    camera = pipeline.camera_for(*stereo_camera_infos(EUROC / "cam0_sensor.yaml", EUROC / "cam1_sensor.yaml"))
    header = make_header(RCLPY_TYPES, 1, "cam0")
    depths, geometries = [], []
    for path in sorted((EUROC / "left").glob("*.png")):
        left, right = (cv2.imread(str(EUROC / side / path.name), cv2.IMREAD_GRAYSCALE) for side in ("left", "right"))
        assert left is not None and right is not None, f"cannot read the EuRoC pair {path.name}"
        frame = StereoFrame(1, header, left, right, camera, rectified=False)
        geometry = result_geometry(pipeline, frame, pipeline.match(left, right, camera))
        depths.append(geometry.depth.copy())
        geometries.append((frame, geometry))
    height, width = depths[0].shape
    print(f"{len(depths)} EuRoC frames {width}x{height}, default profile; medians of {args.repeat} runs")
    print(
        table_header(
            ("depth", "codec", "raw bytes", "compressedDepth bytes", "raw / compressed", "encode ms (wall / CPU)")
        )
    )
    for encoding in ("32FC1", "16UC1"):
        for codec in ("png", "rvl"):
            sizes, walls, cpus = [], [], []
            for depth in depths:
                pixels = depth_pixels(depth, encoding)

                def encode(pixels: np.ndarray = pixels, encoding: str = encoding, codec: str = codec) -> Any:
                    return depth_to_compressed_depth(RCLPY_TYPES, header, pixels, encoding, codec=codec)

                wall, cpu, message = median_ms(encode, args.repeat)
                walls.append(wall)
                cpus.append(cpu)
                sizes.append(len(message.data))
            raw = depths[0].size * (4 if encoding == "32FC1" else 2)
            size = statistics.median(sizes)
            ms = f"{statistics.median(walls):.1f} / {statistics.median(cpus):.1f}"
            print(f"| {encoding} | {codec} | {raw} | {size:.0f} | {raw / size:.1f}x | {ms} |")
    print_codec_per_frame(depths[len(depths) // 2], header)
    options = OutputOptions(max_depth=5.0)
    walls, cpus, widths = [], [], []
    for frame, geometry in geometries:
        state = OutputState()

        def clearing(frame: StereoFrame = frame, geometry: Any = geometry, state: OutputState = state) -> Any:
            fresh = geometry._replace(depth=geometry.depth.copy())  # geometry_outputs limits depth in place
            return geometry_outputs(RCLPY_TYPES, frame.header, fresh, options, ("points2_clearing",), state)

        wall, cpu, messages = median_ms(clearing, args.repeat)
        walls.append(wall)
        cpus.append(cpu)
        widths.append(messages["points2_clearing"].width)
    print(
        f"points2_clearing (max_depth 5 m): {statistics.median(widths):.0f} points, "
        f"{statistics.median(walls):.1f} / {statistics.median(cpus):.1f} ms wall / CPU to build (depth copy included)"
    )


if __name__ == "__main__":
    main()
