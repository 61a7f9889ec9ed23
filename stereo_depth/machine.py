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

from stereo_depth.core.simd import numba_target

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
    target = numba_target()
    source = "NUMBA_CPU_NAME" if target.name_chosen else "host"
    feature_note = "host features" if not target.features_chosen else f"features '{target.features}'"
    return f"{target.level}; target '{target.name}' ({source}), {feature_note}"


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
