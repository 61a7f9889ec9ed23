"""`stereo-depth compile`: build the numba kernels' machine code ahead (the census_sgm core, the temporal
filter, the compressedDepth RVL codec), so no first frame waits for it.

numba compiles the core on its first use (once per install, 30 s to two minutes; cached afterwards). Run
this once after installing (or in a robot image's build step); it prints where the cache went.
"""

from __future__ import annotations

import argparse
import time


def add_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    parser = sub.add_parser("compile", help="compile the census_sgm core now (~30 s once), not on a first frame")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from stereo_depth.core import temporal
    from stereo_depth.core.census_sgm import compile_kernels
    from stereo_depth.core.rvl import rvl_compress

    start = time.perf_counter()
    cache = compile_kernels()
    temporal.compile_kernels()
    rvl_compress(np.zeros((2, 2), np.uint16))
    print(f"census_sgm core ready in {time.perf_counter() - start:.1f} s; numba cache: {cache}")
    return 0
