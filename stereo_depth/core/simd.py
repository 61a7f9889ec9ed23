"""The vector unit numba compiles our kernels for: the host's, or what NUMBA_CPU_NAME / NUMBA_CPU_FEATURES
choose (as benches do to measure another SIMD level on one machine). Kernels that win only with wide
vectors are chosen by it (core/matching.py: our BM at 256 bits or more), and benches print it
(stereo_depth/machine.py)."""

from __future__ import annotations

import functools
from typing import NamedTuple

# LLVM CPU names numba accepts -> the widest vector unit they imply, for NUMBA_CPU_NAME with no feature list
_CPU_NAME_SIMD = {
    "x86-64": "SSE2 (128-bit)",
    "x86-64-v2": "SSE4.2 (128-bit)",
    "x86-64-v3": "AVX2 (256-bit)",
    "haswell": "AVX2 (256-bit)",
    "broadwell": "AVX2 (256-bit)",
    "skylake": "AVX2 (256-bit)",
    "znver2": "AVX2 (256-bit)",
    "znver3": "AVX2 (256-bit)",
    "x86-64-v4": "AVX-512 (512-bit)",
    "skylake-avx512": "AVX-512 (512-bit)",
    "icelake-server": "AVX-512 (512-bit)",
    "sapphirerapids": "AVX-512 (512-bit)",
    "znver4": "AVX-512 (512-bit)",
}


class NumbaTarget(NamedTuple):
    name: str  # LLVM's CPU name
    features: str  # LLVM's feature list ("+avx2,-avx512f,..."); "" with NUMBA_CPU_FEATURES set empty
    name_chosen: bool  # NUMBA_CPU_NAME set
    features_chosen: bool  # NUMBA_CPU_FEATURES set
    level: str  # e.g. "AVX2 (256-bit)"
    vector_bits: int  # 0 where the level is unknown


@functools.cache
def numba_target() -> NumbaTarget:
    """numba's target, read once (numba reads its environment at import)."""
    import llvmlite.binding as llvm
    from numba.core import config

    chosen_name: str | None = getattr(config, "CPU_NAME", None)  # set from the environment at import
    chosen_features: str | None = getattr(config, "CPU_FEATURES", None)
    name = chosen_name or llvm.get_host_cpu_name()
    features = chosen_features if chosen_features is not None else llvm.get_host_cpu_features().flatten()
    enabled = {f[1:] for f in features.split(",") if f.startswith("+")}
    if not features:
        level = _CPU_NAME_SIMD.get(name, "as the CPU name implies")
    elif "avx512f" in enabled:
        level = "AVX-512 (512-bit)"
    elif "avx2" in enabled:
        level = "AVX2 (256-bit)"
    elif "sse4.2" in enabled:
        level = "SSE4.2 (128-bit)"
    else:
        level = "128-bit or less"
    bits = int(level.split("(")[1].split("-")[0]) if "-bit)" in level else 0
    return NumbaTarget(name, features, chosen_name is not None, chosen_features is not None, level, bits)
