"""`stereo-depth compile`: build the numba kernels' machine code ahead (the census_sgm core, our BM, the
temporal and spatial filters, the compressedDepth RVL codec, registered depth), so no first frame waits for it.

numba compiles the core on its first use (once per install, one to two minutes on one core; cached
afterwards). Run this once after installing (or in a robot image's build step); it prints where the cache
went. numba compiles on one thread, so with two cores or more the work goes to two processes (`SHARES`).
"""

from __future__ import annotations

import argparse
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context

# The kernels split into two shares of about equal compile time on a fresh cache (a 2-core Intel Xeon,
# Emerald Rapids: 67 s and 79 s side by side, 140 s in one process): share 0 is the strips' kernel (census_sgm's
# window 1, 6 paths, with its constant-count copies), share 1 every other kernel. Each builds the census
# transform and the post-processing it calls as well.
STRIPS = (1, 6)
SHARES = 2


def add_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    parser = sub.add_parser(
        "compile", help="compile the numba kernels now (one to two minutes once), not on a first frame"
    )
    parser.add_argument(
        "--jobs",
        type=int,
        choices=range(1, SHARES + 1),
        help=f"processes that compile side by side (default: this machine's cores, at most {SHARES})",
    )
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from stereo_depth.core.threads import available_cores

    jobs = args.jobs or min(SHARES, available_cores())
    start = time.perf_counter()
    if jobs > 1:
        # spawn: a fresh interpreter (a fork would copy this one's threads and numba's state)
        with ProcessPoolExecutor(1, mp_context=get_context("spawn")) as pool:
            other = pool.submit(build, 1)
            build(0)
            other.result()
    # everything, in this process: loads what the shares cached, builds what they did not (all with --jobs 1)
    cache = build(None)
    print(f"numba kernels ready in {time.perf_counter() - start:.1f} s ({jobs} processes); numba cache: {cache}")
    return 0


def build(share: int | None) -> str:
    """Compile (or load) the kernels of share 0 or 1 (`SHARES`), or with None all of them; returns the cache
    folder."""
    import numpy as np

    from stereo_depth.core import block_matching, registration, spatial, temporal
    from stereo_depth.core.census_sgm import KERNEL_VARIANTS, compile_kernels
    from stereo_depth.core.rvl import rvl_compress

    variants = [v for v in KERNEL_VARIANTS if share is None or (v == STRIPS) == (share == 0)]
    others = share != 0  # the hole filler, BM, the temporal and spatial filters, the RVL codec, registration
    cache = compile_kernels(variants, fill=others)
    if others:
        block_matching.compile_kernels()
        temporal.compile_kernels()
        spatial.compile_kernels()
        rvl_compress(np.zeros((2, 2), np.uint16))
        registration.compile_registration_kernels()
    return cache
