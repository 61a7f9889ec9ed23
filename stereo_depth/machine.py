"""Which machine a timing came from: CPU model, SIMD level in use, cores and library versions.

Machines of one kind differ about 2x in speed and in vector width (AVX-512 here, AVX2 there, 128-bit NEON
on a Jetson), and numba and OpenCV each pick their SIMD level at run time (NUMBA_CPU_NAME /
NUMBA_CPU_FEATURES, OPENCV_CPU_DISABLE). A time or a ratio means nothing without these, so every bench
and the demo print them first.
"""

from __future__ import annotations

import os
import platform
import time
from importlib import metadata
from pathlib import Path

import cv2

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
LIBRARIES = ("numpy", "opencv-python-headless", "numba", "llvmlite", "ros-jazzy-rclpy", "rosbags")


def cpu_model() -> str:
    for line in _read("/proc/cpuinfo").splitlines():
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return platform.processor() or platform.machine()


def cores() -> str:
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return f"{usable} usable of {os.cpu_count()}"


def numba_simd() -> str:
    """numba's target CPU and the widest vector unit its features allow (what its kernels compile for)."""
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
    source = "NUMBA_CPU_NAME" if chosen_name else "host"
    feature_note = "host features" if chosen_features is None else f"features '{features}'"
    return f"{level}; target '{name}' ({source}), {feature_note}"


def opencv_simd() -> str:
    """OpenCV's dispatched levels as it runs now: '?' marks one the CPU lacks or OPENCV_CPU_DISABLE turned off."""
    disabled = os.environ.get("OPENCV_CPU_DISABLE")
    line = cv2.getCPUFeaturesLine()
    return line + (f" (OPENCV_CPU_DISABLE={disabled})" if disabled else "")


def versions() -> str:
    found = []
    for name in LIBRARIES:
        try:
            found.append(f"{name} {metadata.version(name)}")
        except metadata.PackageNotFoundError:
            continue
    return f"python {platform.python_version()}, " + ", ".join(found)


def machine_lines() -> list[str]:
    return [
        f"CPU: {cpu_model()}, {cores()} cores",
        f"numba SIMD: {numba_simd()}",
        f"OpenCV SIMD: {opencv_simd()}; threads {cv2.getNumThreads()}",
        f"versions: {versions()}",
    ]


def measured_on() -> str:
    """The one line the README puts above each speed table: CPU, cores, both SIMD levels, the date."""
    opencv_levels = [level.strip("*") for level in cv2.getCPUFeaturesLine().split() if not level.endswith("?")]
    widest = opencv_levels[-1] if opencv_levels else "none"
    numba_level = numba_simd().split(";")[0]
    day = time.strftime("%Y-%m-%d")
    return f"Measured on: {cpu_model()}, {cores()} cores; numba {numba_level}, OpenCV up to {widest}; {day}."


def print_machine() -> None:
    """The machine header every bench prints first."""
    for line in machine_lines():
        print(f"# {line}")
    print(flush=True)


def _read(path: str) -> str:
    try:
        return Path(path).read_text()
    except OSError:
        return ""
