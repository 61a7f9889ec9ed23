"""OpenCV's StereoBM, bit for bit, as numba kernels that use the whole width of the CPU's vectors.

OpenCV compiles StereoBM for its baseline instruction set (SSE on x86: 8 sums of absolute differences
per instruction) and runs a second pass over every pixel's 64 or 128 sums for the uniqueness check,
branching every 8 or 16 of them. These kernels do the same arithmetic with the disparity count a
compile-time constant, so LLVM vectorises each pixel's loops at the machine's width (32 sums per
AVX-512 instruction), and test uniqueness branch-free: a pixel is ambiguous when more disparities than
its best and that one's two neighbours have a sum within the ratio of the best.

What OpenCV computes, and so what these do (StereoBM, 16-bit path):
  * prefilter XSOBEL: the horizontal Sobel response of each image, clipped to +-prefilter_cap and
    offset by it, rows taken in pairs (the last row of an odd height, and the first and last column,
    are prefilter_cap itself);
  * for every pixel of the valid region (getValidDisparityROI: every window inside both images) and
    every disparity, the sum of absolute differences of the prefiltered images over the window; the
    best disparity is the largest one with the smallest sum (OpenCV's first minimum over its index,
    which runs from the largest disparity down);
  * invalid where the window's texture (sum of |left - prefilter_cap|) is below texture_threshold, or
    where a disparity other than the best and its neighbours has a sum <= best + best * ratio / 100;
  * the parabola through the best and its neighbours' sums gives 1/16 px, as OpenCV rounds it;
  * everything outside the valid region is invalid: (min_disparity - 1) * 16.
Used on CPUs with 256-bit vectors or wider (`use_our_bm`; at 128 bits OpenCV's is as fast), where
OpenCV takes its 16-bit path (prefilter_cap <= 31, window <= 21: the sums fit int16), without the
left-right check (disp12_max_diff <= 0, stereo_image_proc's default) and with min_disparity <= 0
(above 0 OpenCV matches min_disparity columns past each row's end and writes them into the next row,
where the last valid row's spill survives: its result there is not a function of the images alone);
elsewhere the matcher is OpenCV's own (core/matching.py). numba compiles one kernel
per disparity count on first use (seconds; cached afterwards, `stereo-depth compile` builds 64 and 128
ahead).
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

from stereo_depth.core.params import StereoParams
from stereo_depth.core.simd import numba_target

SHORT_SUMS_MAX_CAP = 31  # OpenCV's 16-bit path: prefilter_cap <= 31 and window <= 21 (62 * 21 * 21 < 2**15)
SHORT_SUMS_MAX_WINDOW = 21
INVALID_SCALE = 16  # OpenCV's fixed point: 1/16 px
WIDE_VECTOR_BITS = 256  # AVX2 and wider


def numba_bm_applies(params: StereoParams) -> bool:
    """Whether these kernels give OpenCV's StereoBM result for `params`."""
    return (
        params.prefilter_cap <= SHORT_SUMS_MAX_CAP
        and params.correlation_window_size <= SHORT_SUMS_MAX_WINDOW
        and params.disp12_max_diff <= 0
        and params.min_disparity <= 0
    )


def use_our_bm(params: StereoParams) -> bool:
    """Ours where they apply and the CPU's vectors are wide enough for them to win: at 128 bits (SSE4.2,
    ARM's NEON) OpenCV's own StereoBM was as fast or faster (bench/bm_kernels.py: 0.96x-1.31x ours)."""
    return numba_bm_applies(params) and numba_target().vector_bits >= WIDE_VECTOR_BITS


def valid_region(width: int, height: int, params: StereoParams) -> tuple[int, int, int, int]:
    """(x0, x1, y0, y1): the pixels OpenCV gives a disparity for whole images: those of getValidDisparityROI
    (every window inside the left image, and inside the right one at every disparity but, up to
    -min_disparity columns from its right edge, where OpenCV reads the right image's last columns instead:
    see `_compiled_band_kernel`) that its column loop reaches (up to width + min_disparity); x1 <= x0 or
    y1 <= y0 when there are none."""
    reach = params.correlation_window_size // 2
    max_disparity = params.min_disparity + params.disparity_range - 1
    x0 = max(0, max_disparity) + reach
    x1 = min(min(width, width - params.min_disparity) - reach, width + params.min_disparity)
    return x0, x1, reach, height - reach


COMPILED_AHEAD = (64, 128)  # disparity counts `stereo-depth compile` builds: the defaults of our profiles


def compile_kernels(disparities: tuple[int, ...] = COMPILED_AHEAD) -> None:
    """Compile the kernels for these disparity counts now (or load them from numba's cache), so that no
    frame waits for them."""
    image = np.zeros((24, max(disparities) + 24), np.uint8)
    for count in disparities:
        params = StereoParams(matcher="bm", disparity_range=count, correlation_window_size=5).validate()
        matcher = BlockMatcher(params)
        matcher.band(matcher.prepare(image, image), 0, image.shape[0])


class BlockMatcher:
    """StereoBM's int16 disparity (1/16 px) for bands of rows of one pair (core/matching.py `Bands`):
    `prepare` prefilters the pair once per frame, then `band` matches each band, on any thread (the
    kernels release the GIL)."""

    def __init__(self, params: StereoParams) -> None:
        self._params = params
        self._prefilter = _prefilter_kernel()
        self._kernel = _compiled_band_kernel(params.disparity_range)
        uniqueness = round(params.uniqueness_ratio)  # OpenCV takes an int (stereo_image_proc rounds it too)
        window, cap = params.correlation_window_size, params.prefilter_cap
        self._settings = (params.min_disparity, window, cap, params.texture_threshold, uniqueness)

    def prepare(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cap = self._params.prefilter_cap
        out = np.empty_like(left), np.empty_like(right)
        self._prefilter(np.ascontiguousarray(left), cap, out[0])
        self._prefilter(np.ascontiguousarray(right), cap, out[1])
        return out

    def band(self, prefiltered: tuple[np.ndarray, np.ndarray], start: int, stop: int, half: int = 0) -> np.ndarray:
        """Rows [start, stop) of the disparity of the whole pair (not of a cut-out band: the windows reach
        into the rows beyond it); `half` is Bands' and changes nothing here."""
        p = self._params
        left, right = prefiltered
        height, width = left.shape
        out = np.full((stop - start, width), (p.min_disparity - 1) * INVALID_SCALE, np.int16)
        x0, x1, y0, y1 = valid_region(width, height, p)
        first, last = max(start, y0), min(stop, y1)
        if x0 < x1 and first < last:
            self._kernel(left, right, *self._settings, first, last, x0, x1, out[first - start : last - start])
        return out


@functools.cache
def _prefilter_kernel() -> Any:
    import numba

    return numba.njit(cache=True, nogil=True)(_prefilter_xsobel)


def _prefilter_xsobel(src: np.ndarray, cap: int, dst: np.ndarray) -> None:
    """OpenCV's prefilterXSobel: rows in pairs, each row's Sobel x response from the rows above and below
    (the row below the first pair's top row stands in for the missing one above it; the pair's own top
    row for the one below the last even pair), clipped to [-cap, cap] and offset by cap."""
    height, width = src.shape
    border = np.uint8(cap)
    y = 0
    while y < height - 1:
        above = src[y - 1] if y > 0 else src[y + 1]
        top, bottom = src[y], src[y + 1]
        below = src[y + 2] if y < height - 2 else src[y]
        out_top, out_bottom = dst[y], dst[y + 1]
        out_top[0] = out_top[width - 1] = out_bottom[0] = out_bottom[width - 1] = border
        for x in range(1, width - 1):
            a = np.int32(above[x + 1]) - np.int32(above[x - 1])
            b = np.int32(top[x + 1]) - np.int32(top[x - 1])
            c = np.int32(bottom[x + 1]) - np.int32(bottom[x - 1])
            d = np.int32(below[x + 1]) - np.int32(below[x - 1])
            out_top[x] = np.uint8(min(max(int(a + 2 * b + c), -cap), cap) + cap)
            out_bottom[x] = np.uint8(min(max(int(b + 2 * c + d), -cap), cap) + cap)
        y += 2
    if y < height:  # an odd height's last row
        dst[y, :] = border


@functools.cache
def _compiled_band_kernel(disparities: int) -> Any:
    """numba's machine code of the band kernel with `disparities` a constant: each pixel's loops over the
    disparities then run as whole vectors, without a remainder loop (numba's cache keys each count apart)."""
    import numba

    nd = disparities

    def match_band(
        left: np.ndarray,
        right: np.ndarray,
        min_disparity: int,
        window: int,
        cap: int,
        texture_threshold: int,
        uniqueness: int,
        first: int,
        last: int,
        x0: int,
        x1: int,
        out: np.ndarray,
    ) -> None:
        """out[y - first, x] for y in [first, last), x in [x0, x1), every window inside both images. Column by
        column, as OpenCV: per row of the band (and the window's reach above and below) the sums over the
        window's columns (`row_sums`, one per disparity index k: right column = x - max_disparity + k),
        moved one column on by adding the entering column and taking the leaving one off; then down the
        column, the window's sums (`sums`) moved one row on the same way. As OpenCV, a column's run of
        right columns stops at the image's last: near the right edge (negative disparities) it starts at
        width - disparities instead."""
        reach = window // 2
        width = left.shape[1]
        max_disparity = min_disparity + nd - 1
        invalid = np.int16((min_disparity - 1) * 16)
        top = first - reach
        band = last - first + 2 * reach
        row_sums = np.zeros((band, nd), np.int16)
        row_texture = np.zeros(band, np.int32)
        sums = np.zeros(nd, np.int16)
        for c in range(x0 - reach, x0 + reach):  # the first window's columns but its last
            for i in range(band):
                value = left[top + i, c]
                r = min(c - max_disparity, width - nd)
                entering = right[top + i, r : r + nd]
                row = row_sums[i]
                for k in range(nd):
                    row[k] = np.int16(row[k] + np.uint8(max(value, entering[k]) - min(value, entering[k])))
                row_texture[i] += abs(np.int32(value) - cap)
        for x in range(x0, x1):
            c_in, c_out = x + reach, x - reach - 1
            r_in, r_out = min(c_in - max_disparity, width - nd), min(c_out - max_disparity, width - nd)
            for i in range(band):
                value = left[top + i, c_in]
                entering = right[top + i, r_in : r_in + nd]
                row = row_sums[i]
                texture = abs(np.int32(value) - cap)
                if x > x0:
                    gone = left[top + i, c_out]
                    leaving = right[top + i, r_out : r_out + nd]
                    for k in range(nd):
                        e, o = entering[k], leaving[k]  # |a - b| as max - min: LLVM keeps it in bytes
                        row[k] = np.int16(
                            row[k]
                            + np.int16(np.uint8(max(value, e) - min(value, e)))
                            - np.int16(np.uint8(max(gone, o) - min(gone, o)))
                        )
                    texture -= abs(np.int32(gone) - cap)
                else:
                    for k in range(nd):
                        row[k] = np.int16(row[k] + np.uint8(max(value, entering[k]) - min(value, entering[k])))
                row_texture[i] += texture
            sums[:] = 0
            window_texture = 0
            for i in range(window - 1):  # the first window's rows but its last
                row = row_sums[i]
                for k in range(nd):
                    sums[k] = np.int16(sums[k] + row[k])
                window_texture += row_texture[i]
            for y in range(first, last):
                i = y - top + reach  # the entering row
                row = row_sums[i]
                window_texture += row_texture[i]
                best = np.int16(32767)
                if y > first:
                    gone_row = row_sums[i - window]
                    window_texture -= row_texture[i - window]
                    for k in range(nd):
                        s = np.int16(sums[k] + row[k] - gone_row[k])
                        sums[k] = s
                        best = min(best, s)
                else:
                    for k in range(nd):
                        s = np.int16(sums[k] + row[k])
                        sums[k] = s
                        best = min(best, s)
                if window_texture < texture_threshold:
                    out[y - first, x] = invalid
                    continue
                limit = np.int16(best + best * uniqueness // 100)
                k_best = np.int16(32767)
                within = np.int16(0)
                for k in range(nd):
                    s = sums[k]
                    k_best = min(k_best, np.int16(k) if s == best else np.int16(32767))
                    within += np.int16(s <= limit)
                kb = np.int32(k_best)
                if uniqueness > 0:
                    near = 1  # the best itself
                    if kb > 0 and sums[kb - 1] <= limit:
                        near += 1
                    if kb < nd - 1 and sums[kb + 1] <= limit:
                        near += 1
                    if within > near:
                        out[y - first, x] = invalid
                        continue
                disparity = max_disparity - kb
                if 0 < kb < nd - 1:
                    p = np.int32(sums[kb + 1])
                    n = np.int32(sums[kb - 1])
                    den = p + n - 2 * np.int32(best) + abs(p - n)
                    step = np.int32(0)
                    if den != 0:  # C's integer division truncates towards zero
                        step = abs(p - n) * 256 // den
                        step = step if p >= n else -step
                    out[y - first, x] = np.int16((disparity * 256 + step + 15) >> 4)
                else:
                    out[y - first, x] = np.int16(disparity * 16)

    return numba.njit(cache=True, nogil=True)(match_band)
