"""The census core's matching against OpenCV's SGBM 3-way at three SIMD levels of this machine, interleaved.

One child process per level (native, AVX2, 128-bit: lib/simd.py SIMD_ENV, each with its own numba
cache, compiled and warmed up first) keeps the matchers loaded; the parent asks each child in turn for
one frame of each profile (each after a 50 ms pause, so no thread pool still spins from the match
before), `--repeat` times, so a load change on the machine hits every level alike.
Per level: the CPU and SIMD levels the child sees (stereo_depth.machine), median match ms of `default`
(OpenCV SGBM 3-way), `quality` (census_sgm, 6 paths) and `quality` with `census_paths:=8` and `:=5`, and
their ratios against `default`. 640x480 EuRoC pair, 128 disparities.

    .venv/bin/python bench/simd_match_ratio.py [--repeat 15] [--levels native avx2 128] [--markdown]
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from lib.interleaved import IDLE_S
from lib.simd import LEVEL_COLUMNS, level_cells, run_levels, serve_level
from lib.table import table_header, table_row, times

# (name, profile, overrides): OpenCV SGBM 3-way, then census_sgm with 6 paths (the profile), 8 and 5
PROFILES: tuple[tuple[str, str, dict[str, int]], ...] = (
    ("default", "default", {}),
    ("quality", "quality", {}),
    ("quality 8 paths", "quality", {"census_paths": 8}),
    ("quality 5 paths", "quality", {"census_paths": 5}),
)


def child(disparity_range: int) -> None:
    """Serve frames: print the machine as this level sees it, then one line of match ms per line read."""
    from pipeline_stages import load_pair

    from stereo_depth.core.params import make_params
    from stereo_depth.core.pipeline import StereoPipeline

    left, right, camera = load_pair(640, 480)
    pipelines = {
        name: StereoPipeline(make_params(profile, {"disparity_range": disparity_range, **overrides}))
        for name, profile, overrides in PROFILES
    }

    def frame() -> dict[str, float]:
        ms = {}
        for name, pipeline in pipelines.items():
            time.sleep(IDLE_S)
            ms[name] = pipeline.match(left, right, camera).timings_ms["match"]
        return ms

    serve_level(frame)


def main() -> None:
    args, machines, runs = run_levels(__file__, __doc__.splitlines()[0], 128, child)
    names = [name for name, _, _ in PROFILES]
    columns = (*LEVEL_COLUMNS, *(f"{n} ms" for n in names), *(f"{n} / default" for n in names[1:]))
    print(f"640x480, {args.disparity_range} disparities, {args.repeat} frames per level, interleaved")
    if args.markdown:
        print(table_header(columns))
    for level, frames in runs.items():
        ms = {n: statistics.median(f[n] for f in frames) for n in names}
        cells = (*level_cells(level, machines[level]), *(f"{ms[n]:.1f}" for n in names))
        cells += tuple(times(ms[n] / ms["default"]) for n in names[1:])
        print(table_row(cells) if args.markdown else "  ".join(cells))


if __name__ == "__main__":
    main()
