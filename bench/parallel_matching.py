"""Which matchers use every core by themselves, and which gain from matching two frames at once.

For each matcher setting: frames/s of one thread matching frame after frame, against two threads each
matching with a matcher of its own (as stereo_node's `matching_threads:=2` does), same frames, same
run. A throughput ratio near 1 means the matcher already keeps the cores busy; near the core count,
that it runs on one core. This is what `matching_threads:=0` (auto) decides from
(`stereo_depth.core.matching.runs_on_one_core`).

    .venv/bin/python bench/parallel_matching.py [--size 640x480] [--frames 10]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import threading
import time
from pathlib import Path

import cv2

from stereo_depth.core.matching import create_matcher, runs_on_one_core
from stereo_depth.core.params import make_params

sys.path.insert(0, str(Path(__file__).parent))
from anchor_frames import frames

SETTINGS = {
    "bm (stereo_image_proc)": make_params("stereo_image_proc"),
    "sgbm mode SGBM (stereo_algorithm:=1)": make_params("stereo_image_proc", {"stereo_algorithm": 1}),
    "sgbm mode HH": make_params("stereo_image_proc", {"stereo_algorithm": 1, "sgbm_mode": 1}),
    "sgbm mode SGBM_3WAY (default)": make_params("default"),
    "census_sgm (quality)": make_params("quality"),
}


def seconds_per_frame(matchers: list, left: object, right: object, count: int) -> float:
    def run(matcher: object) -> None:
        for _ in range(count):
            matcher.compute(left, right)  # type: ignore[attr-defined]

    threads = [threading.Thread(target=run, args=(m,)) for m in matchers]
    start = time.perf_counter()
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    return (time.perf_counter() - start) / (count * len(matchers))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--size", default="640x480")
    parser.add_argument("--frames", type=int, default=10)
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
    ((left, right),) = list(frames(width, height, 1))
    print(f"OpenCV {cv2.__version__}, {cv2.getNumThreads()} threads, {width}x{height}, anchor frames")
    print(f"{'matcher':38s} {'1 thread ms':>11s} {'2 threads ms':>12s} {'throughput':>10s}  auto threads")
    for name, params in SETTINGS.items():
        params = dataclasses.replace(params, disparity_range=64)
        matchers = [create_matcher(params) for _ in range(2)]
        for matcher in matchers:
            matcher.compute(left, right)  # warm-up (numba loads its cache here)
        one = seconds_per_frame(matchers[:1], left, right, args.frames)
        two = seconds_per_frame(matchers, left, right, args.frames)
        auto = 2 if runs_on_one_core(params) else 1
        print(f"{name:38s} {one * 1e3:11.1f} {two * 1e3:12.1f} {one / two:9.2f}x  {auto}")


if __name__ == "__main__":
    main()
