"""What keeping freed memory (stereo_depth/core/memory.py) saves per frame: page faults and time, interleaved.

Two child processes at one SIMD level: `kept` (as every StereoPipeline sets it) and `glibc` (malloc's own
thresholds, the call skipped). The parent asks each in turn for one frame of each profile, `--repeat`
times (each after a 50 ms pause, as bench/simd_match_ratio.py), so a load change hits both alike. A frame
is the pipeline's match (the matching ratio's stage) and the whole `process` (rectify, match, depth,
points). Per profile: median ms and page faults (minor, of the whole process) per frame. 640x480 EuRoC
pair, 128 disparities.

    .venv/bin/python bench/page_faults.py [--repeat 15] [--simd avx2] [--profiles default quality]
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import sys
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from interleaved import IDLE_S, frames_in_turn, serve, start
from markdown_table import parse_bench_arguments, table_header, table_row, times
from readme_figures import SIMD_ENV, simd_env

VARIANTS = ("glibc", "kept")


def child(variant: str, profiles: list[str], disparity_range: int) -> None:
    from pipeline_stages import load_pair

    from stereo_depth.core import memory
    from stereo_depth.core.params import make_params
    from stereo_depth.core.pipeline import StereoPipeline

    if variant == "glibc":
        memory._kept.append(False)  # as if done: the pipelines below leave malloc as glibc sets it
    left, right, camera = load_pair(640, 480)
    pipelines = {p: StereoPipeline(make_params(p, {"disparity_range": disparity_range})) for p in profiles}

    def measured(work: Callable[[], object]) -> tuple[float, int]:
        time.sleep(IDLE_S)
        faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        began = time.perf_counter()
        work()
        ms = (time.perf_counter() - began) * 1000.0
        return ms, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults

    def frame() -> dict[str, tuple[float, int]]:
        out = {}
        for name, pipeline in pipelines.items():
            out[f"{name} match"] = measured(partial(pipeline.match, left, right, camera))
            out[f"{name} process"] = measured(partial(pipeline.process, left, right, camera))
        return out

    serve(frame, "ready")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=15)
    parser.add_argument("--simd", choices=list(SIMD_ENV), default="native")
    parser.add_argument("--profiles", nargs="+", default=["stereo_image_proc", "default", "quality"])
    parser.add_argument("--disparity-range", type=int, default=128)
    parser.add_argument("--child", choices=VARIANTS, help=argparse.SUPPRESS)
    if "--child" in sys.argv:
        args = parser.parse_args()
        child(args.child, args.profiles, args.disparity_range)
        return
    args = parse_bench_arguments(parser)
    common = ["--profiles", *args.profiles, "--disparity-range", str(args.disparity_range)]
    env = {**os.environ, **simd_env(args.simd)}
    children = {v: start([__file__, "--child", v, *common], env) for v in VARIANTS}
    _, runs = frames_in_turn(children, args.repeat)
    print(f"640x480, {args.disparity_range} disparities, SIMD level {args.simd}, {args.repeat} frames, interleaved")
    columns = ("profile", "stage", "glibc ms", "kept ms", "kept / glibc", "glibc faults", "kept faults")
    print(table_header(columns) if args.markdown else "  ".join(columns))
    for key in runs["kept"][0]:
        ms = {v: statistics.median(f[key][0] for f in runs[v]) for v in VARIANTS}
        faults = {v: statistics.median(f[key][1] for f in runs[v]) for v in VARIANTS}
        name, stage = key.rsplit(" ", 1)
        time_cells = (f"{ms['glibc']:.1f}", f"{ms['kept']:.1f}", times(ms["kept"] / ms["glibc"]))
        cells = (name, stage, *time_cells, f"{faults['glibc']:.0f}", f"{faults['kept']:.0f}")
        print(table_row(cells) if args.markdown else "  ".join(cells))


if __name__ == "__main__":
    main()
