"""SIMD levels on one machine: the environment that makes numba and OpenCV use a narrower level than the
CPU has (for `make bench-docs --simd` and for benches that run one child process per level, each with its
own numba cache, asked for frames in turn: bench/simd_match_ratio.py and bench/bm_kernels.py)."""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from lib.interleaved import frames_in_turn, serve, start
from lib.table import parse_bench_arguments

# the environment that makes numba and OpenCV use that level on a wider machine
SIMD_ENV = {
    "native": {},
    "avx2": {"NUMBA_CPU_NAME": "haswell", "NUMBA_CPU_FEATURES": "", "OPENCV_CPU_DISABLE": "AVX512-SKX"},
    "128": {
        "NUMBA_CPU_NAME": "x86-64-v2",
        "NUMBA_CPU_FEATURES": "",
        "OPENCV_CPU_DISABLE": "AVX,AVX2,AVX512-SKX,FP16",
    },
}


def simd_env(level: str) -> dict[str, str]:
    """SIMD_ENV of that level, with a numba cache folder of its own (~/.cache/stereo_depth/numba_<level>)."""
    cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "stereo_depth" / f"numba_{level}"
    return {**SIMD_ENV[level], "NUMBA_CACHE_DIR": str(cache)}


def run_levels(
    script: str, description: str, disparity_range: int, child: Callable[[int], None]
) -> tuple[argparse.Namespace, dict[str, Any], dict[str, list[Any]]]:
    """The bench's command line (`--repeat`, `--levels`, `--disparity-range`, `--markdown`); in a child
    (`--child`), `child(disparity_range)` and exit; else (args, each level's machine, each level's frames)."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--repeat", type=int, default=15)
    parser.add_argument("--levels", nargs="+", choices=list(SIMD_ENV), default=list(SIMD_ENV))
    parser.add_argument("--disparity-range", type=int, default=disparity_range)
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    if "--child" in sys.argv:
        child(parser.parse_args().disparity_range)
        raise SystemExit(0)
    args = parse_bench_arguments(parser)
    arguments = [script, "--child", "--disparity-range", str(args.disparity_range)]
    children = {level: start(arguments, {**os.environ, **simd_env(level)}) for level in args.levels}
    machines, runs = frames_in_turn(children, args.repeat)
    return args, machines, runs


def serve_level(frame: Callable[[], dict[str, float]]) -> None:
    """The child's side: the machine as this level sees it, then one frame's figures per line read."""
    from stereo_depth.machine import cpu_model, numba_simd, opencv_simd

    serve(frame, {"cpu": cpu_model(), "numba": numba_simd(), "opencv": opencv_simd()})


LEVEL_COLUMNS = ("level", "CPU", "numba SIMD", "OpenCV SIMD")


def level_cells(level: str, machine: dict[str, str]) -> tuple[str, str, str, str]:
    """The first cells of a level's row: the level, the CPU, and the SIMD levels numba and OpenCV use there."""
    numba_level = machine["numba"].split(";")[0]
    opencv_widest = [x.strip("*") for x in machine["opencv"].split("(")[0].split() if not x.endswith("?")][-1]
    return level, machine["cpu"], numba_level, f"up to {opencv_widest}"
