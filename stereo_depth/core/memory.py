"""Freed memory kept in the process for the next frame, instead of handed back to the kernel.

Every frame allocates and frees buffers of the same sizes: images, disparities, clouds, the census
core's intermediates (about 7 MB a frame at 640x480). glibc raises its mmap threshold to the largest
block freed so far, but hands blocks above it back to the kernel on free and trims the heap's free
top above twice it, per thread's arena: with the census core, or frames of several sizes, the next
frame's buffers fault their pages in again, zero-filled (~2,000 page faults and ~3-5 ms of a 640x480
`quality` frame, docs/design/decisions.md). Fixed thresholds keep those pages in the process for reuse;
the process then stays at its peak size instead of shrinking between frames.
"""

from __future__ import annotations

import ctypes

M_TRIM_THRESHOLD = -1  # glibc's mallopt parameters (malloc.h)
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD = 32 << 20  # glibc's largest on 64-bit: blocks above it (the census volumes) still come from mmap
TRIM_THRESHOLD = 256 << 20  # free memory at the heap's top handed back only beyond this

_kept: list[bool] = []


def keep_freed_memory() -> bool:
    """Set the thresholds once per process; False where the C library has no mallopt (not glibc)."""
    if not _kept:
        mallopt = getattr(ctypes.CDLL(None), "mallopt", None)
        _kept.append(
            mallopt is not None
            and mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD) == 1
            and mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD) == 1
        )
    return _kept[0]
