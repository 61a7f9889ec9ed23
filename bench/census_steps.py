"""Where the census core's time goes: census_sgm step by step, against OpenCV's SGBM 3-way in the same run.

The `quality` profile's matcher (6 paths) and the same with `census_paths:=8` and `:=5`, on the rectified
640x480 EuRoC pair (bench/pipeline_stages.py), 128 disparities, with the time of each census_sgm step
(census transform; Hamming costs, path aggregation and winner selection, which run fused in one kernel;
median; speckles; gap closing). Two more rows split the fused kernel: the Hamming costs alone, as a whole
cost volume on the same two threads (`_hamming_volume`, what window_size > 1 computes before its box sum),
and OpenCV's SGBM 3-way (`default`), whose whole match is the baseline of the ratio column. Frames
interleave the matchers, each after a short idle pause (bench/interleaved.py), so a load change on the
machine hits all alike; medians over `--repeat` frames. Set the `--simd` variables of
bench/readme_figures.py to measure another SIMD level.

    .venv/bin/python bench/census_steps.py [--repeat 15] [--markdown]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from stereo_depth.core.census_sgm import STEPS, aggregation, census
from stereo_depth.core.matching import CensusSGMMatcher, create_matcher
from stereo_depth.core.params import make_params

sys.path.insert(0, str(Path(__file__).parent))
from interleaved import IDLE_S
from markdown_table import parse_bench_arguments, table_header, table_row, times
from pipeline_stages import load_pair

PATHS = (6, 8, 5)
COSTS_ALONE = "Hamming costs alone (whole volume, 2 threads)"
WHOLE = "census_sgm, all steps"
BASELINE = "default: OpenCV SGBM 3-way, whole match"


def rectified_pair() -> tuple[np.ndarray, np.ndarray]:
    left, right, camera = load_pair(640, 480)
    return camera.rectify(left, "left"), camera.rectify(right, "right")


def costs_alone(left: np.ndarray, right: np.ndarray, disparities: int) -> float:
    """ms of the Hamming cost volume of the pair (the quality profile's census), census not included."""
    cl, cr = census.census_pair(left, right, census.CENSUS_SIZE)
    volume, _ = aggregation._workspace(left.shape, disparities)
    start = time.perf_counter()
    aggregation._hamming_volume(cl, cr, 0, volume)
    return (time.perf_counter() - start) * 1000.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=15)
    parser.add_argument("--disparity-range", type=int, default=128)
    args = parse_bench_arguments(parser)
    left, right = rectified_pair()
    nd = args.disparity_range
    baseline = create_matcher(make_params("default", {"disparity_range": nd}))
    matchers: dict[int, CensusSGMMatcher] = {}
    for paths in PATHS:
        matcher = create_matcher(make_params("quality", {"disparity_range": nd, "census_paths": paths}))
        assert isinstance(matcher, CensusSGMMatcher)
        matchers[paths] = matcher
    for matcher in (baseline, *matchers.values()):  # compiles or loads the kernels, warms the caches
        matcher.compute(left, right)
    costs_alone(left, right, nd)
    runs: dict[str, list[float]] = {}
    for _ in range(args.repeat):
        time.sleep(IDLE_S)
        start = time.perf_counter()
        baseline.compute(left, right)
        runs.setdefault(BASELINE, []).append((time.perf_counter() - start) * 1000.0)
        time.sleep(IDLE_S)
        runs.setdefault(COSTS_ALONE, []).append(costs_alone(left, right, nd))
        for paths, matcher in matchers.items():
            time.sleep(IDLE_S)
            matcher.compute(left, right)
            for step in STEPS:
                runs.setdefault(f"{paths} {step}", []).append(matcher.step_ms[step])
            runs.setdefault(f"{paths} {WHOLE}", []).append(sum(matcher.step_ms.values()))
    ms = {name: statistics.median(values) for name, values in runs.items()}
    default_ms = ms[BASELINE]
    columns = ("step", *(f"{p} paths ms" for p in PATHS), f"{PATHS[0]} paths / default match")
    print(f"640x480 EuRoC pair, {nd} disparities, {args.repeat} frames, interleaved; {time.strftime('%Y-%m-%d')}")
    print(table_header(columns) if args.markdown else "  ".join(columns))
    rows = [
        (step, *(f"{ms[f'{p} {step}']:.1f}" for p in PATHS), times(ms[f"{PATHS[0]} {step}"] / default_ms))
        for step in (*STEPS, WHOLE)
    ]
    rows.append((COSTS_ALONE, f"{ms[COSTS_ALONE]:.1f}", "", "", times(ms[COSTS_ALONE] / default_ms)))
    rows.append((BASELINE, f"{default_ms:.1f}", "", "", times(1.0)))
    for row in rows:
        print(table_row(row) if args.markdown else "  ".join(row))


if __name__ == "__main__":
    main()
