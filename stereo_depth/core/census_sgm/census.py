"""The census transform: a 7x9 window's comparisons with its centre, as bits of one uint64 per pixel.

Census is used rather than absolute differences because it is invariant to gain/offset changes
between the cameras (Middlebury ``*_e``/``*_l`` variants, KITTI auto-exposure).
"""

from __future__ import annotations

import cv2
import numpy as np

from stereo_depth.core.census_sgm.registry import kernel as _kernel

prange = range  # replaced by numba.prange before any kernel is compiled (registry.compile_all)
CENSUS_SIZE = (7, 9)  # (height, width): 62 bits


def census_pair(left: np.ndarray, right: np.ndarray, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The census images of a pair, the right one reversed along its rows (see aggregation._hamming_pixel)."""
    half_h, half_w = size[0] // 2, size[1] // 2
    cl = _census(_pad(left, half_h, half_w), half_h, half_w)
    return cl, np.ascontiguousarray(_census(_pad(right, half_h, half_w), half_h, half_w)[:, ::-1])


@_kernel(parallel=True)
def _census(padded: np.ndarray, half_h: int, half_w: int) -> np.ndarray:
    """Census bit string per pixel: bit set where the neighbour is darker than the centre.

    ``padded`` has the image border replicated by (half_h, half_w). Bits are gathered 16 at a
    time in uint16 words (16 SIMD lanes where uint64 gives 4) and shifted into the uint64 per
    word; the bit order is the same for both images, which is all a Hamming distance needs.
    """
    h = padded.shape[0] - 2 * half_h
    w = padded.shape[1] - 2 * half_w
    out = np.zeros((h, w), np.uint64)
    for y in prange(h):
        centre = padded[y + half_h, half_w : half_w + w]
        bits = out[y]
        word = np.zeros(w, np.uint16)
        n = 0
        for dy in range(2 * half_h + 1):
            for dx in range(2 * half_w + 1):
                if dy == half_h and dx == half_w:
                    continue
                row = padded[y + dy, dx : dx + w]
                for x in range(w):
                    word[x] = (word[x] << np.uint16(1)) | np.uint16(row[x] < centre[x])
                n += 1
                if n == 16:
                    for x in range(w):
                        bits[x] = (bits[x] << np.uint64(16)) | np.uint64(word[x])
                        word[x] = 0
                    n = 0
        if n > 0:
            for x in range(w):
                bits[x] = (bits[x] << np.uint64(16)) | np.uint64(word[x])
    return out


def _pad(img: np.ndarray, half_h: int, half_w: int) -> np.ndarray:
    """Replicate the border so the census window never leaves the image."""
    return cv2.copyMakeBorder(img, half_h, half_h, half_w, half_w, cv2.BORDER_REPLICATE)
