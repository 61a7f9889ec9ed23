"""Our BM kernels against OpenCV's StereoBM (the same int16 disparity, core/block_matching.py) at three SIMD
levels of this machine, interleaved.

One child process per level (native, AVX2, 128-bit: lib/simd.py SIMD_ENV, each with its own numba
cache), each serving frames of the anchor's 640x480 stream (bench/lib/anchor_frames.py) with
stereo_image_proc's parameters (BM, window 15) and `--disparity-range` disparities; the parent asks the
children in turn (bench/lib/interleaved.py). Per frame and level, each way after a 50 ms pause:
  * the whole image on one thread: OpenCV's StereoBM (its stripes on one OpenCV thread), and ours;
  * stereo_node's match: both halves at once on two cores with their speckles removed (core/matching.py
    `Halves`), with OpenCV's matcher on each half (`OpenCVBands`) and with ours (`BlockMatcher`).
Prints the median ms of each and ours / OpenCV's. OpenCV builds StereoBM for its baseline (SSE2 on x86),
so its figures should not move with the level; ours use the level's full vector width (the node takes
ours at 256 bits and wider only: core/block_matching.py `use_our_bm`).

    .venv/bin/python bench/bm_kernels.py [--repeat 15] [--levels native avx2 128] [--disparity-range 64] [--markdown]
"""

from __future__ import annotations

import functools
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from lib.anchor_frames import frames
from lib.interleaved import IDLE_S
from lib.simd import LEVEL_COLUMNS, level_cells, run_levels, serve_level
from lib.table import table_header, table_row, times

WAYS = ("OpenCV, 1 thread", "ours, 1 thread", "OpenCV, halves", "ours, halves")


def child(disparity_range: int) -> None:
    """Serve frames: print the machine as this level sees it, then one line of ms per way per line read."""
    import cv2

    from stereo_depth.core.block_matching import BlockMatcher
    from stereo_depth.core.matching import create_bm, opencv_bm
    from stereo_depth.core.params import make_params
    from stereo_depth.core.threads import opencv_threads

    params = make_params("stereo_image_proc", {"disparity_range": disparity_range})
    pairs = list(frames(640, 480, 20))
    opencv, ours = opencv_bm(params, 0), BlockMatcher(params)
    halves = {
        "OpenCV, halves": create_bm(params, our_kernels=False),
        "ours, halves": create_bm(params, our_kernels=True),
    }
    assert isinstance(vars(halves["ours, halves"])["_bands"], BlockMatcher)
    count = [0]

    def timed(work: Callable[[], object]) -> float:
        time.sleep(IDLE_S)
        start_s = time.perf_counter()
        work()
        return (time.perf_counter() - start_s) * 1000.0

    def frame() -> dict[str, float]:
        left, right = pairs[count[0] % len(pairs)]
        count[0] += 1
        cv2.setNumThreads(2)
        ms = {}
        with opencv_threads(1):
            ms["OpenCV, 1 thread"] = timed(lambda: opencv.compute(left, right))
            ms["ours, 1 thread"] = timed(lambda: ours.band(ours.prepare(left, right), 0, left.shape[0]))
        for name, matcher in halves.items():
            ms[name] = timed(functools.partial(matcher.compute, left, right))
        return ms

    serve_level(frame)


def main() -> None:
    args, machines, runs = run_levels(__file__, __doc__.splitlines()[0], 64, child)
    print(f"BM 640x480 (anchor frames), {args.disparity_range} disparities, window 15, {args.repeat} frames")
    columns = (*LEVEL_COLUMNS, *(f"{w} ms" for w in WAYS), "ours / OpenCV, 1 thread")
    if args.markdown:
        print(table_header((*columns, "ours / OpenCV, halves")))
    for level, runs_of_level in runs.items():
        ms = {w: statistics.median(f[w] for f in runs_of_level) for w in WAYS}
        cells = (*level_cells(level, machines[level]), *(f"{ms[w]:.2f}" for w in WAYS))
        cells += (times(ms[WAYS[1]] / ms[WAYS[0]]), times(ms[WAYS[3]] / ms[WAYS[2]]))
        print(table_row(cells) if args.markdown else "  ".join(cells))


if __name__ == "__main__":
    main()
