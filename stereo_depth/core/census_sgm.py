"""Census-transform + semi-global matching core, and an edge-aware hole filler.

The recipe is the standard CPU one (Zabih & Woodfill census, Hirschmueller SGM):

    census (7x9 window, 62 bits in one uint64)
      -> Hamming cost volume C[y, x, d] (uint16, optionally box-summed over ``window_size``)
      -> 8-path scanline aggregation S = sum_r L_r, P2 shrunk across intensity edges
      -> winner-take-all + uniqueness on S
      -> right disparity from the same S (argmin along the diagonal), left-right check
      -> parabola sub-pixel fit -> NaN-aware 3x3 median -> speckle removal.

Census is used rather than absolute differences because it is invariant to gain/offset changes
between the cameras (Middlebury ``*_e``/``*_l`` variants, KITTI auto-exposure).

Every per-pixel loop is a numba kernel compiled with ``cache=True``, so a fresh process loads
machine code from the cache instead of spending seconds recompiling. numba itself is imported on
the first call (see ``_kernels``), so importing this module costs no more than numpy + OpenCV.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

import cv2
import numpy as np

__all__ = ["census_sgm", "fill_holes"]

_F = TypeVar("_F", bound=Callable[..., Any])

#: Kernels waiting for ``numba.njit``; compiled (or loaded from the cache) on first use.
_PENDING: dict[str, tuple[Callable[..., Any], bool, bool]] = {}
_READY: list[bool] = []

prange = range  # replaced by numba.prange before any kernel is compiled

_SENTINEL = 0x3FFF  # "infinite" path cost in padded disparity slots; two of them still fit in uint16


def _kernel(*, parallel: bool = False, fastmath: bool = True) -> Callable[[_F], _F]:
    """Mark a function as a numba kernel without importing numba at module import time.

    Kernels that test for NaN must pass ``fastmath=False``: fastmath lets LLVM assume no NaNs
    and fold ``np.isnan`` to False.
    """

    def mark(fn: _F) -> _F:
        _PENDING[fn.__name__] = (fn, parallel, fastmath)
        return fn

    return mark


def _kernels() -> None:
    """Swap every marked function for its numba dispatcher (once per process).

    The swap goes through ``globals()`` so kernels that call kernels, and ``prange``, resolve to
    numba objects when numba compiles them; ``cache=True`` keys on file and qualname, so the cache
    written by one process is reused by the next.
    """
    if _READY:
        return
    import numba  # noqa: PLC0415  (deliberately lazy: ~0.5 s import)

    module = globals()
    module["prange"] = numba.prange
    for name, (fn, parallel, fastmath) in _PENDING.items():
        module[name] = numba.njit(cache=True, parallel=parallel, fastmath=fastmath, nogil=True)(fn)
    _READY.append(True)


# ----------------------------------------------------------------------------------------------
# kernels
# ----------------------------------------------------------------------------------------------


@_kernel(parallel=True)
def _census(img: np.ndarray, half_h: int, half_w: int) -> np.ndarray:
    """Census bit string per pixel: bit set where the neighbour is darker than the centre.

    Borders replicate the edge pixel so the descriptor is defined everywhere.
    """
    h, w = img.shape
    out = np.zeros((h, w), np.uint64)
    for y in prange(h):
        for x in range(w):
            c = img[y, x]
            bits = np.uint64(0)
            for dy in range(-half_h, half_h + 1):
                yy = min(max(y + dy, 0), h - 1)
                for dx in range(-half_w, half_w + 1):
                    if dy == 0 and dx == 0:
                        continue
                    xx = min(max(x + dx, 0), w - 1)
                    bits = (bits << np.uint64(1)) | np.uint64(img[yy, xx] < c)
            out[y, x] = bits
    return out


@_kernel()
def _popcount(v: np.uint64) -> np.uint64:
    """SWAR popcount (numba exposes no popcnt intrinsic)."""
    v = v - ((v >> np.uint64(1)) & np.uint64(0x5555555555555555))
    v = (v & np.uint64(0x3333333333333333)) + ((v >> np.uint64(2)) & np.uint64(0x3333333333333333))
    v = (v + (v >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return (v * np.uint64(0x0101010101010101)) >> np.uint64(56)


@_kernel(parallel=True)
def _hamming_volume(cl: np.ndarray, cr: np.ndarray, min_d: int, nd: int) -> np.ndarray:
    """C[y, x, k] = Hamming(census_left(x), census_right(x - min_d - k)).

    Right columns left of the image are clamped to column 0: the cost stays finite (it only feeds
    the aggregation) and the winner search later ignores those disparities.
    """
    h, w = cl.shape
    vol = np.empty((h, w, nd), np.uint16)
    for y in prange(h):
        for x in range(w):
            a = cl[y, x]
            for k in range(nd):
                xr = min(max(x - min_d - k, 0), w - 1)
                vol[y, x, k] = np.uint16(_popcount(a ^ cr[y, xr]))
    return vol


@_kernel(parallel=True)
def _box_volume(vol: np.ndarray, half: int) -> np.ndarray:
    """Box-sum the cost volume over a (2*half+1)^2 window: a small support stabilises SGM on noise."""
    h, w, nd = vol.shape
    tmp = np.empty((h, w, nd), np.uint16)
    out = np.empty((h, w, nd), np.uint16)
    for y in prange(h):
        acc = np.zeros(nd, np.uint16)
        for x in range(w):
            for k in range(nd):
                acc[k] = 0
            for dx in range(-half, half + 1):
                xx = min(max(x + dx, 0), w - 1)
                for k in range(nd):
                    acc[k] = np.uint16(acc[k] + vol[y, xx, k])
            for k in range(nd):
                tmp[y, x, k] = acc[k]
    for y in prange(h):
        acc = np.zeros(nd, np.uint16)
        for x in range(w):
            for k in range(nd):
                acc[k] = 0
            for dy in range(-half, half + 1):
                yy = min(max(y + dy, 0), h - 1)
                for k in range(nd):
                    acc[k] = np.uint16(acc[k] + tmp[yy, x, k])
            for k in range(nd):
                out[y, x, k] = acc[k]
    return out


@_kernel()
def _path_step(
    cost: np.ndarray,  # (nd,) uint16 matching cost at p
    prev: np.ndarray,  # (nd+2,) uint16 L_r(p - r), sentinels at both ends
    prev_min: np.uint16,
    cur: np.ndarray,  # (nd+2,) out: L_r(p)
    acc: np.ndarray,  # (nd,) uint16 S(p), accumulated in place
    p1: np.uint16,
    p2: np.uint16,
) -> np.uint16:
    """One SGM recurrence step; returns min_d L_r(p). Written branch-free so LLVM vectorises it."""
    nd = cost.shape[0]
    jump = np.uint16(prev_min + p2)
    new_min = np.uint16(0xFFFF)
    for k in range(nd):
        best = min(min(prev[k + 1], jump), np.uint16(min(prev[k], prev[k + 2]) + p1))
        v = np.uint16(cost[k] + best - prev_min)
        cur[k + 1] = v
        new_min = min(new_min, v)
        acc[k] = np.uint16(acc[k] + v)
    return new_min


@_kernel()
def _edge_p2(a: np.uint8, b: np.uint8, p1: int, p2: int, gamma: float) -> np.uint16:
    """P2 divided by the intensity step between neighbours: depth jumps are cheap across edges."""
    g = abs(np.int32(a) - np.int32(b))
    return np.uint16(max(p1 + 1, int(p2 / (1.0 + g / gamma))))


@_kernel()
def _start_path(cost: np.ndarray, buf: np.ndarray, acc: np.ndarray) -> np.uint16:
    """First pixel of a path: L_r = C."""
    nd = cost.shape[0]
    m = np.uint16(0xFFFF)
    for k in range(nd):
        buf[k + 1] = cost[k]
        acc[k] = np.uint16(acc[k] + cost[k])
        m = min(m, cost[k])
    return m


@_kernel(parallel=True)
def _aggregate_rows(vol: np.ndarray, img: np.ndarray, acc: np.ndarray, p1: int, p2: int, gamma: float) -> None:
    """Left-to-right and right-to-left paths; rows are independent so they run in parallel."""
    h, w, nd = vol.shape
    q1 = np.uint16(p1)
    for y in prange(h):
        a = np.full(nd + 2, _SENTINEL, np.uint16)
        b = np.full(nd + 2, _SENTINEL, np.uint16)
        m = _start_path(vol[y, 0], a, acc[y, 0])
        for x in range(1, w):
            q2 = _edge_p2(img[y, x], img[y, x - 1], p1, p2, gamma)
            m = _path_step(vol[y, x], a, m, b, acc[y, x], q1, q2)
            a, b = b, a
        m = _start_path(vol[y, w - 1], a, acc[y, w - 1])
        for x in range(w - 2, -1, -1):
            q2 = _edge_p2(img[y, x], img[y, x + 1], p1, p2, gamma)
            m = _path_step(vol[y, x], a, m, b, acc[y, x], q1, q2)
            a, b = b, a


@_kernel(parallel=True)
def _vertical_row(
    vol: np.ndarray, img: np.ndarray, acc: np.ndarray, y: int, step: int,
    prev: np.ndarray, prev_min: np.ndarray, cur: np.ndarray, cur_min: np.ndarray,
    p1: int, p2: int, gamma: float, ndirs: int,
) -> None:
    """One row of the vertical (+ diagonal) paths; the previous row's L lives in ``prev``.

    Direction j uses dx = (0, -1, +1)[j]: the predecessor of (y, x) is (y - step, x - dx).
    """
    h, w, nd = vol.shape
    q1 = np.uint16(p1)
    for x in prange(w):
        for j in range(ndirs):
            dx = 0 if j == 0 else (-1 if j == 1 else 1)
            px = x - dx
            if y == (0 if step == 1 else h - 1) or px < 0 or px >= w:
                cur_min[j, x] = _start_path(vol[y, x], cur[j, x], acc[y, x])
            else:
                q2 = _edge_p2(img[y, x], img[y - step, px], p1, p2, gamma)
                cur_min[j, x] = _path_step(vol[y, x], prev[j, px], prev_min[j, px], cur[j, x], acc[y, x], q1, q2)


@_kernel()
def _aggregate_columns(
    vol: np.ndarray, img: np.ndarray, acc: np.ndarray, p1: int, p2: int, gamma: float, ndirs: int
) -> None:
    """Top-down then bottom-up sweeps; each row is parallel over columns."""
    h, w, nd = vol.shape
    for step in (1, -1):
        prev = np.full((ndirs, w, nd + 2), _SENTINEL, np.uint16)
        cur = np.full((ndirs, w, nd + 2), _SENTINEL, np.uint16)
        prev_min = np.zeros((ndirs, w), np.uint16)
        cur_min = np.zeros((ndirs, w), np.uint16)
        y = 0 if step == 1 else h - 1
        for _ in range(h):
            _vertical_row(vol, img, acc, y, step, prev, prev_min, cur, cur_min, p1, p2, gamma, ndirs)
            prev, cur = cur, prev
            prev_min, cur_min = cur_min, prev_min
            y += step


@_kernel(parallel=True)
def _select(
    acc: np.ndarray, min_d: int, uniqueness: float, disp12: int, conf_gain: float, lr_penalty: float
) -> tuple[np.ndarray, np.ndarray]:
    """Winner-take-all on S for both views, uniqueness + left-right check, parabola, confidence.

    The right view's disparity at xr is argmin_k S[y, xr + min_d + k, k]: the same aggregated
    volume read along the diagonal, so no second matching pass is needed.
    """
    h, w, nd = acc.shape
    disp = np.full((h, w), np.nan, np.float32)
    conf = np.zeros((h, w), np.float32)
    for y in prange(h):
        right_best = np.full(w, 0xFFFFFFFF, np.uint32)
        right_k = np.full(w, -1, np.int32)
        left_k = np.full(w, -1, np.int32)
        ratio = np.zeros(w, np.float32)
        sub = np.zeros(w, np.float32)
        for x in range(w):
            kmax = min(nd, x - min_d + 1)  # right column x - min_d - k must be >= 0
            if kmax <= 0:
                continue
            row = acc[y, x]
            best = np.uint32(0xFFFFFFFF)
            bk = 0
            for k in range(kmax):
                v = np.uint32(row[k])
                if v < best:
                    best = v
                    bk = k
                xr = x - min_d - k
                if v < right_best[xr]:
                    right_best[xr] = v
                    right_k[xr] = k
            second = np.uint32(0xFFFFFFFF)
            for k in range(kmax):
                if abs(k - bk) > 1:
                    second = min(second, np.uint32(row[k]))
            if second != 0xFFFFFFFF and second * (1.0 - uniqueness) < best:
                continue
            left_k[x] = bk
            ratio[x] = 1.0 if second == 0xFFFFFFFF else (second - best) / max(second, 1)
            delta = 0.0
            if 0 < bk < kmax - 1:
                lo = np.float32(row[bk - 1])
                hi = np.float32(row[bk + 1])
                den = lo + hi - 2.0 * np.float32(best)
                if den > 0:
                    delta = (lo - hi) / (2.0 * den)
            sub[x] = delta
        for x in range(w):
            bk = left_k[x]
            if bk < 0:
                continue
            rk = right_k[x - min_d - bk]
            diff = abs(rk - bk)
            if disp12 >= 0 and diff > disp12:
                continue
            disp[y, x] = min_d + bk + sub[x]
            c = min(1.0, ratio[x] * conf_gain)
            if diff > 0:
                c *= lr_penalty
            conf[y, x] = c
    return disp, conf


@_kernel(parallel=True, fastmath=False)
def _nan_median3(disp: np.ndarray) -> np.ndarray:
    """3x3 median over the valid neighbours of each valid pixel; holes stay holes.

    Removes single-pixel outliers and WTA staircase noise without bleeding into invalid areas.
    """
    h, w = disp.shape
    out = disp.copy()
    for y in prange(h):
        buf = np.empty(9, np.float32)
        for x in range(w):
            if np.isnan(disp[y, x]):
                continue
            n = 0
            for yy in range(max(y - 1, 0), min(y + 2, h)):
                for xx in range(max(x - 1, 0), min(x + 2, w)):
                    v = disp[yy, xx]
                    if not np.isnan(v):
                        buf[n] = v
                        n += 1
            out[y, x] = np.sort(buf[:n])[n // 2]
    return out


# ----------------------------------------------------------------------------------------------
# public API
# ----------------------------------------------------------------------------------------------


def census_sgm(
    left: np.ndarray,
    right: np.ndarray,
    *,
    min_disparity: int,
    num_disparities: int,
    window_size: int,
    P1: float,  # noqa: N803  (stereo_image_proc parameter name)
    P2: float,  # noqa: N803
    uniqueness_ratio: float,
    disp12_max_diff: int,
    census_size: tuple[int, int] = (7, 9),
    p2_gamma: float = 8.0,
    paths: int = 8,
    median: bool = True,
    speckle_size: int = 100,
    speckle_range: float = 2.0,
    conf_gain: float = 4.0,
    lr_penalty: float = 0.5,
) -> tuple[np.ndarray, np.ndarray]:
    """Census + SGM disparity of a rectified pair.

    left/right: rectified uint8 grey HxW, left is the reference. Returns (disparity, confidence):
    disparity float32 HxW in pixels with d = x_left - x_right, sub-pixel, NaN where invalid
    (failed LR check, not unique, outside search range); confidence float32 HxW in [0, 1]
    (0 where invalid).

    ``window_size`` box-sums the Hamming costs (1 = census only; odd). P1/P2 are in units of
    census bits x window area. ``uniqueness_ratio`` is a percentage as in OpenCV; ``disp12_max_diff``
    < 0 disables the left-right check. ``census_size`` is (height, width), at most 63 bits.
    ``paths`` is 4 (horizontal + vertical) or 8. ``speckle_size`` 0 disables speckle removal.
    Confidence is the cost margin (second - best) / second times ``conf_gain``, clipped to 1 and
    scaled by ``lr_penalty`` where the two views disagree by a pixel.
    """
    _check_inputs(left, right, num_disparities, window_size, census_size, paths)
    _kernels()
    ch, cw = census_size
    cl = _census(left, ch // 2, cw // 2)
    cr = _census(right, ch // 2, cw // 2)
    vol = _hamming_volume(cl, cr, int(min_disparity), int(num_disparities))
    if window_size > 1:
        vol = _box_volume(vol, window_size // 2)
    acc = np.zeros_like(vol)
    p1, p2 = int(P1), int(P2)
    _aggregate_rows(vol, left, acc, p1, p2, float(p2_gamma))
    _aggregate_columns(vol, left, acc, p1, p2, float(p2_gamma), 1 if paths == 4 else 3)
    del vol
    disp, conf = _select(
        acc, int(min_disparity), uniqueness_ratio / 100.0, int(disp12_max_diff), conf_gain, lr_penalty
    )
    if median:
        disp = _nan_median3(disp)
    if speckle_size > 0:
        disp = _remove_speckles(disp, speckle_size, speckle_range)
    conf[np.isnan(disp)] = 0.0
    return disp, conf


def _check_inputs(
    left: np.ndarray, right: np.ndarray, nd: int, window: int, census: tuple[int, int], paths: int
) -> None:
    """Refuse inputs the kernels would silently mis-handle."""
    if left.dtype != np.uint8 or right.dtype != np.uint8 or left.ndim != 2 or left.shape != right.shape:
        msg = f"census_sgm needs two uint8 grey images of one size, got {left.dtype}{left.shape} and {right.dtype}{right.shape}"
        raise ValueError(msg)
    if nd < 1:
        msg = f"num_disparities must be >= 1, got {nd}"
        raise ValueError(msg)
    if window < 1 or window % 2 == 0:
        msg = f"window_size must be odd and >= 1, got {window}"
        raise ValueError(msg)
    if census[0] % 2 == 0 or census[1] % 2 == 0 or census[0] * census[1] - 1 > 64:
        msg = f"census_size must be odd x odd with at most 64 neighbours, got {census}"
        raise ValueError(msg)
    if paths not in (4, 8):
        msg = f"paths must be 4 or 8, got {paths}"
        raise ValueError(msg)


def _remove_speckles(disp: np.ndarray, size: int, max_diff: float) -> np.ndarray:
    """Drop small connected blobs that differ from their surroundings (OpenCV's speckle filter).

    Works on 1/16 px fixed point so neighbouring sub-pixel values stay connected.
    """
    invalid = np.int16(-32768)
    fixed = np.where(np.isnan(disp), invalid, np.round(disp * 16.0)).astype(np.int16)
    cv2.filterSpeckles(fixed, int(invalid), int(size), int(round(max_diff * 16)))
    out = disp.copy()
    out[fixed == invalid] = np.nan
    return out


def fill_holes(disparity: np.ndarray, left: np.ndarray) -> np.ndarray:
    """Fill every NaN so density is 1.0, favouring the background and following image edges.

    Holes are mostly occlusions next to a foreground edge, where the correct value is the far
    (smaller) disparity of the occluded surface; a plain scanline fill drags the foreground in.
    """
    _kernels()
    disp = np.ascontiguousarray(disparity, dtype=np.float32)
    if not np.isnan(disp).any():
        return disp.copy()
    if np.isnan(disp).all():
        return np.zeros_like(disp)
    grey = left if left.ndim == 2 else cv2.cvtColor(left, cv2.COLOR_BGR2GRAY)
    return _fill_kernel(disp, np.ascontiguousarray(grey, dtype=np.uint8))


@_kernel(parallel=True, fastmath=False)
def _fill_kernel(disp: np.ndarray, img: np.ndarray) -> np.ndarray:
    """Scanline background fill: each hole takes the smaller of its nearest valid row neighbours."""
    h, w = disp.shape
    out = disp.copy()
    for y in prange(h):
        last = np.nan
        for x in range(w):
            if np.isnan(disp[y, x]):
                nxt = np.nan
                for xx in range(x + 1, w):
                    if not np.isnan(disp[y, xx]):
                        nxt = disp[y, xx]
                        break
                if np.isnan(last):
                    out[y, x] = nxt
                elif np.isnan(nxt):
                    out[y, x] = last
                else:
                    out[y, x] = min(last, nxt)
            else:
                last = disp[y, x]
    return out
