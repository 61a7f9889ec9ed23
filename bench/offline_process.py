"""Offline: `stereo-depth process` frames/s against a bare OpenCV loop over the same bag, same run.

The input is the anchor's synthetic stream (bench/lib/anchor_frames.py: mono8, textured layers, 64 px of
disparity) written to an uncompressed MCAP rosbag2. Ours is the real command line
(`python -m stereo_depth.cli process IN OUT --profile P [options]`, its own frames/s line: read, sync,
pipeline, outputs serialized into a new bag), in the variants of VARIANTS: every output (about 12 MB a
VGA frame, mostly points2) as uncompressed MCAP, zstd MCAP and sqlite3, and the disparity alone.
The bare loop is what a hand-written script does with the same
bag: rosbags reader + CDR deserialize, np.frombuffer, remap x2 (maps built once), the same OpenCV
matcher, cv2.reprojectImageTo3D; it writes nothing. "not written" is `process`'s per-frame work without
the storage (read, pair, pipeline, every output message serialized-ready), in this process: the part
that compares like for like with the bare loop. Runs alternate (ours, bare, ours, bare, ...) and the
table gives the median of each and the ratio ours / bare.

    .venv/bin/python bench/offline_process.py [--frames 150] [--repeats 3] [--profiles stereo_image_proc] [--markdown]
"""

from __future__ import annotations

import argparse
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from rosbags.rosbag2 import Reader

from stereo_depth.bag.process import ProcessOptions
from stereo_depth.bag.reader import StereoBagReader
from stereo_depth.bag.types import rosbags_types, typestore
from stereo_depth.bag.writer import BagWriter
from stereo_depth.core.camera import StereoCamera
from stereo_depth.core.matching import whole_image
from stereo_depth.core.params import make_params
from stereo_depth.frames import FrameStream
from stereo_depth.messages import array_to_image, camera_info_to_msg, make_header

sys.path.insert(0, str(Path(__file__).parent))
from lib.anchor_frames import FRAME_ID, camera_infos, frames
from lib.table import parse_bench_arguments, table_header, table_row, times

NAMESPACE = "/stereo"
PERIOD_NS = 33_333_333


def write_bag(path: Path, width: int, height: int, count: int) -> None:
    types = rosbags_types()
    infos = camera_infos(width, height)
    with BagWriter(path, compress=False) as writer:
        for i, (left, right) in enumerate(frames(width, height, count)):
            stamp = 1_700_000_000 * 10**9 + i * PERIOD_NS
            header = make_header(types, stamp, FRAME_ID)
            writer.write(f"{NAMESPACE}/left/image_raw", array_to_image(types, header, left), stamp)
            writer.write(f"{NAMESPACE}/left/camera_info", camera_info_to_msg(types, header, infos[0]), stamp)
            writer.write(f"{NAMESPACE}/right/image_raw", array_to_image(types, header, right), stamp)
            writer.write(f"{NAMESPACE}/right/camera_info", camera_info_to_msg(types, header, infos[1]), stamp)


# `process` variants timed: label -> extra command-line options
VARIANTS = {
    "process, mcap": [],
    "process, mcap --compress": ["--compress"],
    "process, sqlite3": ["--storage", "sqlite3"],
    "process --outputs disparity": ["--outputs", "disparity"],
}


def ours(bag: Path, out: Path, profile: str, options: list[str]) -> float:
    """frames/s as `stereo-depth process` reports it (its own clock: bag open to bag closed)."""
    cmd = [sys.executable, "-m", "stereo_depth.cli", "process", str(bag), str(out), "--profile", profile, *options]
    done = subprocess.run([*cmd, "--overwrite"], capture_output=True, text=True, check=True)
    found = re.search(r"([0-9.]+) frames/s", done.stdout + done.stderr)
    if found is None:
        sys.exit(f"no frames/s in the output of {' '.join(cmd)}:\n{done.stdout}{done.stderr}")
    return float(found.group(1))


def ours_unwritten(bag: Path, profile: str) -> float:
    """frames/s of what `process` does per frame without the storage: read + pair, pipeline, every output
    message built (stereo_depth.bag.process's own functions), nothing written."""
    types, params, options = rosbags_types(), make_params(profile), ProcessOptions()
    start = time.perf_counter()
    done = 0
    with StereoBagReader(bag) as reader:
        names, rectified = reader.topics.input_names, reader.topics.rectified
        stream = FrameStream(types, params, options.output, rectified=rectified, names=names)
        for inputs in reader.frames():
            out = stream.match(inputs, options.outputs)
            if out.cloud is not None:
                out.cloud.run()
            done += 1
    return done / (time.perf_counter() - start)


def bare(bag: Path, profile: str) -> float:
    """frames/s of the hand-written loop: deserialize, pair by stamp, remap x2, match, reproject."""
    store = typestore()
    matcher = whole_image(make_params(profile))
    start = time.perf_counter()
    done = 0
    waiting: dict[tuple[int, str], np.ndarray] = {}
    maps: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    with Reader(bag) as reader:
        for connection, _, raw in reader.messages():
            msg: Any = store.deserialize_cdr(raw, connection.msgtype)
            side = "left" if "/left/" in connection.topic else "right"
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            if connection.topic.endswith("camera_info"):
                if side not in maps:
                    k, p = msg.k.reshape(3, 3), msg.p.reshape(3, 4)
                    size = (int(msg.width), int(msg.height))
                    maps[side] = cv2.initUndistortRectifyMap(k, msg.d, msg.r.reshape(3, 3), p, size, cv2.CV_16SC2)
                continue
            waiting[(stamp, side)] = np.frombuffer(msg.data, np.uint8).reshape(msg.height, msg.width)
            other = (stamp, "right" if side == "left" else "left")
            if other not in waiting or len(maps) < 2:
                continue
            left, right = waiting.pop((stamp, "left")), waiting.pop((stamp, "right"))
            rl = cv2.remap(left, *maps["left"], cv2.INTER_LINEAR)
            rr = cv2.remap(right, *maps["right"], cv2.INTER_LINEAR)
            disparity = matcher.compute(rl, rr).disparity
            cv2.reprojectImageTo3D(disparity, _camera(left.shape).q)
            done += 1
    return done / (time.perf_counter() - start)


_cameras: dict[tuple[int, ...], StereoCamera] = {}


def _camera(shape: tuple[int, ...]) -> StereoCamera:
    """Q for reprojectImageTo3D, built once per size (a script would write the 4x4 by hand)."""
    if shape not in _cameras:
        _cameras[shape] = StereoCamera(*camera_infos(shape[1], shape[0]))
    return _cameras[shape]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=150)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--profiles", nargs="+", default=["stereo_image_proc", "default"])
    parser.add_argument("--sizes", nargs="+", default=["640x480", "1280x720"])
    parser.add_argument("--variants", nargs="+", choices=list(VARIANTS), default=list(VARIANTS), metavar="V")
    args = parse_bench_arguments(parser)
    load = Path("/proc/loadavg").read_text().split()[:3]
    print(f"OpenCV {cv2.__version__}, {cv2.getNumThreads()} threads, {args.frames} frames, load {' '.join(load)}")
    if args.markdown:
        print(table_header(("profile", "size", "output", "frames/s", "bare loop frames/s", "vs bare loop")))
    else:
        print(f"{'profile':18s}{'size':>10s}{'output':>30s}{'ours f/s':>10s}{'bare f/s':>10s}{'ratio':>7s}")
    with tempfile.TemporaryDirectory(prefix="offline_bench_") as tmp:
        for size in args.sizes:
            width, height = (int(v) for v in size.split("x"))
            bag = Path(tmp) / f"in_{size}"
            write_bag(bag, width, height, args.frames)
            for profile in args.profiles:
                mine: dict[str, list[float]] = {variant: [] for variant in args.variants}
                mine["not written"] = []
                theirs = []
                for _ in range(args.repeats):
                    for variant in args.variants:
                        mine[variant].append(ours(bag, Path(tmp) / "out", profile, VARIANTS[variant]))
                    mine["not written"].append(ours_unwritten(bag, profile))
                    theirs.append(bare(bag, profile))
                bare_fps = statistics.median(theirs)
                for output, values in mine.items():
                    fps = statistics.median(values)
                    if args.markdown:
                        cells = (profile, size, output, f"{fps:.1f}", f"{bare_fps:.1f}", times(fps / bare_fps))
                        print(table_row(cells), flush=True)
                        continue
                    row = f"{profile:18s}{size:>10s}{output:>30s}{fps:10.1f}{bare_fps:10.1f}{fps / bare_fps:7.2f}"
                    print(row, flush=True)


if __name__ == "__main__":
    main()
