"""Does a match run slower after the cores sat idle? A node at 30 Hz idles between frames.

The same BM matcher (stereo_image_proc's parameters, both halves at once as stereo_node runs it) on the
anchor's VGA frames, in interleaved rounds: frame after frame; with an idle gap (sleep) before each
frame; and with the same gap spent spinning, so the machine never idles. Prints the
median ms per frame of each and its ratio to frame after frame. Where the clock follows the load (a
utilization-driven frequency governor, on the host of a VM or on the machine itself) the gap row slows
down as the pattern goes on and the spinning row does not; without that effect all three agree. The
slowdown builds up over frames: 1.09x with 10 frames a round, 1.23x with 20, 1.95x with 60 on the
README's 2-core Xeon VM (AVX-512).

    .venv/bin/python bench/idle_gap.py [--gap-ms 20] [--frames 60] [--rounds 3]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

from stereo_depth.core.matching import create_bm
from stereo_depth.core.params import make_params

sys.path.insert(0, str(Path(__file__).parent))
from anchor_frames import frames
from markdown_table import parse_bench_arguments, table_header, table_row, times


def spin(seconds: float) -> None:
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        pass


def gap(mode: str, seconds: float) -> None:
    if mode == "idle gap":
        time.sleep(seconds)
    elif mode == "gap spent spinning":
        spin(seconds)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--gap-ms", type=float, default=20.0, help="idle time before each frame")
    parser.add_argument("--frames", type=int, default=60, help="frames per round and mode")
    parser.add_argument("--rounds", type=int, default=3)
    args = parse_bench_arguments(parser)
    matcher = create_bm(make_params("stereo_image_proc"))
    pairs = list(frames(640, 480, 20))
    modes = ("frame after frame", "idle gap", "gap spent spinning")
    ms: dict[str, list[float]] = {mode: [] for mode in modes}
    for _ in range(args.rounds):
        for mode in modes:
            for i in range(args.frames):
                gap(mode, args.gap_ms / 1000.0)
                left, right = pairs[i % len(pairs)]
                start = time.perf_counter()
                matcher.compute(left, right)
                ms[mode].append((time.perf_counter() - start) * 1000.0)
    baseline = statistics.median(ms[modes[0]])
    print(f"BM 640x480, 64 disparities, window 15; gap {args.gap_ms:g} ms; {args.rounds} rounds x {args.frames} frames")
    if args.markdown:
        print(table_header(("before each frame", "ms per frame (median)", "vs frame after frame")))
    for mode in modes:
        median = statistics.median(ms[mode])
        cells = (mode, f"{median:.2f}", times(median / baseline))
        print(table_row(cells) if args.markdown else f"{cells[0]:28s} {cells[1]:>6s} ms  {cells[2]}")


if __name__ == "__main__":
    main()
