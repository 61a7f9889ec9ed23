"""RVL, the lossless depth codec of compressed_depth_image_transport (A. Wilson, "Fast Lossless Depth
Image Compression", 2017), as that package's RvlCodec::CompressRVL writes it, byte for byte.

Per run of pixels: the count of zeros, the count of nonzeros, then each nonzero as the zigzag-coded
difference to the previous nonzero (the first to 0). Each count and difference is written in 3-bit
groups, low group first, bit 3 set while more groups follow; eight 4-bit groups fill a 32-bit word
from its top bits down, words in little-endian order, the last one zero-filled.

A sequential loop by nature, so it is a numba kernel (compiled on first use, cached afterwards), as
the census_sgm core's are; numba is imported only when RVL is asked for.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import numpy as np


def rvl_compress(pixels: np.ndarray) -> np.ndarray:
    """The RVL bytes of a uint16 image (no width / height prefix: the caller's format adds that)."""
    flat = np.ascontiguousarray(pixels, dtype=np.uint16).reshape(-1)
    words = np.zeros(flat.size * 3 // 4 + 8, np.uint32)  # at most 6 groups (3 bytes) a pixel, and two counts
    used = _kernel()(flat, words)
    return words[:used].astype("<u4", copy=False).view(np.uint8)


@functools.cache
def _kernel() -> Callable[[np.ndarray, np.ndarray], int]:
    import numba

    emit = numba.njit(cache=True, inline="always")(_emit)
    globals()["_emit"] = emit  # what the compressor's body calls, resolved when numba compiles it
    compress: Callable[[np.ndarray, np.ndarray], int] = numba.njit(cache=True, nogil=True)(_compress)
    return compress


def _emit(value: int, words: np.ndarray, state: np.ndarray) -> None:
    """One value's 3-bit groups into the word stream; state: [word, groups in it, words written]."""
    while True:
        nibble = value & 7
        value >>= 3
        if value:
            nibble |= 8
        state[0] = (state[0] << 4) | nibble
        state[1] += 1
        if state[1] == 8:
            words[state[2]] = state[0] & 0xFFFFFFFF
            state[2] += 1
            state[0] = 0
            state[1] = 0
        if not value:
            return


def _compress(pixels: np.ndarray, words: np.ndarray) -> int:
    state = np.zeros(3, np.int64)
    n = pixels.size
    i = 0
    previous = 0
    while i < n:
        zeros = 0
        while i < n and pixels[i] == 0:
            i += 1
            zeros += 1
        _emit(zeros, words, state)
        nonzeros = 0
        while i + nonzeros < n and pixels[i + nonzeros] != 0:
            nonzeros += 1
        _emit(nonzeros, words, state)
        for _ in range(nonzeros):
            current = int(pixels[i])
            i += 1
            delta = current - previous
            _emit((delta << 1) ^ (delta >> 31), words, state)
            previous = current
    if state[1]:
        words[state[2]] = (state[0] << (4 * (8 - state[1]))) & 0xFFFFFFFF
        state[2] += 1
    return int(state[2])
