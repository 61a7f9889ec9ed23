"""What compressed input costs: a VGA stereo frame as raw sensor_msgs/Image, and as image_transport's
JPEG and PNG sensor_msgs/CompressedImage, decoded the way the node and `process` decode it
(frames.decode_image, on rclpy messages) and then through the default pipeline.

Raw, JPEG and PNG run interleaved in one process on the same pixels (real EuRoC greyscale frames and
the bundled colour scene `artl`, both resized to 640x480), so the ratios compare like with like; the
table gives medians of both images' decode and of the whole frame (decode + rectify/match/filter/depth),
each as a ratio to raw input measured in the same run, and the bytes on the wire per image.

    flock /tmp/stereo_depth_cpu.lock .venv/bin/python bench/compressed_input.py [--repeat 30] [--markdown]
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from lib.table import parse_bench_arguments, table_header, table_row, times
from pipeline_stages import scaled_info

from stereo_depth.core.camera import StereoCamera
from stereo_depth.core.params import make_params
from stereo_depth.core.pipeline import StereoPipeline
from stereo_depth.formats.euroc import stereo_camera_infos
from stereo_depth.formats.scenes import load_scene
from stereo_depth.frames import decode_image
from stereo_depth.messages import array_to_compressed, array_to_image, make_header
from stereo_depth.ros.types import RCLPY_TYPES

ROOT = Path(__file__).resolve().parents[1]
EUROC = ROOT / "test" / "data" / "euroc"
VGA = (640, 480)
KINDS = ("raw", "jpeg", "png")


def read_grey(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    assert image is not None, path
    return image


def euroc_pair() -> tuple[np.ndarray, np.ndarray, StereoCamera]:
    """Real raw greyscale frames, resized; the calibration scaled with them (as bench/pipeline_stages)."""
    name = sorted((EUROC / "left").glob("*.png"))[0].name
    left, right = (cv2.resize(read_grey(EUROC / side / name), VGA) for side in ("left", "right"))
    info_l, info_r = stereo_camera_infos(EUROC / "cam0_sensor.yaml", EUROC / "cam1_sensor.yaml")
    return left, right, StereoCamera(scaled_info(info_l, *VGA), scaled_info(info_r, *VGA))


def colour_pair() -> tuple[np.ndarray, np.ndarray, StereoCamera]:
    scene = load_scene(ROOT / "test" / "data" / "scenes" / "artl")
    left_info, right_info = scene.camera_infos()
    camera = StereoCamera(scaled_info(left_info, *VGA), scaled_info(right_info, *VGA))
    return cv2.resize(scene.left, VGA), cv2.resize(scene.right, VGA), camera


def messages(pixels: np.ndarray, kind: str) -> Any:
    header = make_header(RCLPY_TYPES, 1, "cam")
    if kind == "raw":
        return array_to_image(RCLPY_TYPES, header, pixels)
    return array_to_compressed(RCLPY_TYPES, header, pixels, kind)


def timed(work: Callable[[], object]) -> float:
    start = time.perf_counter()
    work()
    return (time.perf_counter() - start) * 1000.0


def measure(
    name: str, pair: tuple[np.ndarray, np.ndarray, StereoCamera], repeat: int, markdown: bool = False
) -> list[str]:
    left, right, camera = pair
    inputs = {kind: (messages(left, kind), messages(right, kind)) for kind in KINDS}
    pipeline = StereoPipeline(make_params())
    decode: dict[str, list[float]] = {kind: [] for kind in KINDS}
    frame: dict[str, list[float]] = {kind: [] for kind in KINDS}

    def decode_both(kind: str) -> tuple[np.ndarray, np.ndarray]:
        return decode_image(inputs[kind][0]), decode_image(inputs[kind][1])

    def whole_frame(kind: str) -> None:
        pipeline.process(*decode_both(kind), camera, want_points=False)

    for kind in KINDS:  # warm-up: maps, matcher, first decode
        whole_frame(kind)
    for _ in range(repeat):
        for kind in KINDS:
            decode[kind].append(timed(partial(decode_both, kind)))
            frame[kind].append(timed(partial(whole_frame, kind)))
    raw_decode, raw_frame = statistics.median(decode["raw"]), statistics.median(frame["raw"])
    rows = []
    for kind in KINDS:
        size = len(bytes(inputs[kind][0].data))
        d, f = statistics.median(decode[kind]), statistics.median(frame[kind])
        if markdown:
            cells = (name, kind, f"{size / 1024:.0f}", f"{d:.2f}", f"{f:.1f}", times(f / raw_frame))
            rows.append(table_row(cells))
            continue
        rows.append(
            f"{name:14s} {kind:5s} {size / 1024:10.0f} {d:10.2f} {d / raw_decode:9.1f}x {f:10.1f} {f / raw_frame:9.2f}x"
        )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=30)
    args = parse_bench_arguments(parser)
    print(f"VGA {VGA[0]}x{VGA[1]}, default profile, medians of {args.repeat} interleaved runs")
    columns = ("KiB/img", "decode ms", "vs raw", "frame ms", "vs raw")
    if args.markdown:
        print(table_header(("frames", "input", "KiB per image", "decode ms (pair)", "frame ms", "frame vs raw")))
    else:
        print(f"{'frames':14s} {'input':5s} " + " ".join(f"{c:>10s}" for c in columns))
    for name, pair in (("euroc mono8", euroc_pair()), ("artl bgr8", colour_pair())):
        for row in measure(name, pair, args.repeat, args.markdown):
            print(row)


if __name__ == "__main__":
    main()
