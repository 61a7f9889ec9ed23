"""How our matchers use two cores: halves of one frame at once, or two frames at once.

For each matcher setting, same frames, same run: ms per frame matching frame after frame on one
thread, and ms per frame with two threads each matching frames with a matcher of their own (as
stereo_node's `matching_threads:=2` does); a throughput ratio near 1 means one frame already keeps
both cores busy. OpenCV SGBM's SGBM and HH modes aggregate on one core by themselves; our matcher
runs them, and BM, on two overlapping halves at once (matching.Halves, bit-identical output): the "OpenCV
whole image" rows time the plain OpenCV call for comparison.

    .venv/bin/python bench/parallel_matching.py [--size 640x480] [--frames 10] [--markdown]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import threading
import time
from pathlib import Path

import cv2
import numpy as np

from stereo_depth.core import matching
from stereo_depth.core.matching import Matcher, create_matcher
from stereo_depth.core.params import StereoParams, make_params

sys.path.insert(0, str(Path(__file__).parent))
from anchor_frames import frames
from markdown_table import parse_bench_arguments, table_header, table_row, times

SGBM = make_params("stereo_image_proc", {"stereo_algorithm": 1})
HH = make_params("stereo_image_proc", {"stereo_algorithm": 1, "sgbm_mode": 1})
# (name, parameters, True: the plain OpenCV call on the whole image instead of our matcher)
SETTINGS = [
    ("bm (stereo_image_proc)", make_params("stereo_image_proc"), False),
    ("  OpenCV whole image", make_params("stereo_image_proc"), True),
    ("sgbm mode SGBM (stereo_algorithm:=1)", SGBM, False),
    ("  OpenCV whole image", SGBM, True),
    ("sgbm mode HH", HH, False),
    ("  OpenCV whole image", HH, True),
    ("sgbm mode SGBM_3WAY (default)", make_params("default"), False),
    ("census_sgm (quality)", make_params("quality"), False),
]


def matcher_for(params: StereoParams, whole_image: bool) -> Matcher:
    if whole_image:
        return matching.whole_image(params)
    return create_matcher(params)


def seconds_per_frame(matchers: list[Matcher], left: np.ndarray, right: np.ndarray, count: int) -> float:
    def run(matcher: Matcher) -> None:
        for _ in range(count):
            matcher.compute(left, right)

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
    args = parse_bench_arguments(parser)
    width, height = (int(v) for v in args.size.split("x"))
    ((left, right),) = list(frames(width, height, 1))
    print(f"OpenCV {cv2.__version__}, {cv2.getNumThreads()} threads, {width}x{height}, anchor frames")
    if args.markdown:
        print(table_header(("matcher", "1 frame ms", "2 at once, ms per frame", "rate 2 / 1", "whole image / ours")))
    else:
        print(f"{'matcher':38s} {'1 frame ms':>10s} {'2 at once ms':>12s} {'throughput':>10s}")
    ours_ms = 0.0
    for name, params, whole_image in SETTINGS:
        params = dataclasses.replace(params, disparity_range=64)
        matchers = [matcher_for(params, whole_image) for _ in range(2)]
        for matcher in matchers:
            matcher.compute(left, right)  # warm-up (numba loads its cache here)
        one = seconds_per_frame(matchers[:1], left, right, args.frames)
        two = seconds_per_frame(matchers, left, right, args.frames)
        if args.markdown:  # whole-image rows: how much sooner our halves-at-once matcher (the row above) is
            sooner = times(one * 1e3 / ours_ms) if whole_image else ""
            print(
                table_row((name.strip(), f"{one * 1e3:.1f}", f"{two * 1e3:.1f}", times(one / two), sooner)), flush=True
            )
        else:
            print(f"{name:38s} {one * 1e3:10.1f} {two * 1e3:12.1f} {one / two:9.2f}x")
        ours_ms = one * 1e3


if __name__ == "__main__":
    main()
