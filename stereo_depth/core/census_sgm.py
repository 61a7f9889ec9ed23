"""Census-transform + semi-global matching core, and an edge-aware hole filler.

The recipe is the standard CPU one (Zabih & Woodfill census, Hirschmueller SGM):

    census (7x9 window, 62 bits in one uint64)
      -> Hamming cost volume C[y, x, d] (uint16, optionally box-summed over ``window_size``)
      -> 8-path scanline aggregation S = sum_r L_r, P2 shrunk across intensity edges
      -> winner-take-all + uniqueness on S
      -> right disparity from the same S (argmin along the diagonal), left-right check
      -> parabola sub-pixel fit -> NaN-aware 3x3 median -> speckle removal
      -> gap closing: short consistent row gaps interpolated, occlusion-shaped gaps and the
         left-border strip given the background value beside them.

Census is used rather than absolute differences because it is invariant to gain/offset changes
between the cameras (Middlebury ``*_e``/``*_l`` variants, KITTI auto-exposure).

Every per-pixel loop is a numba kernel compiled with ``cache=True``, so a fresh process loads
machine code from the cache instead of spending seconds recompiling. numba itself is imported on
the first call (see ``_kernels``), so importing this module costs no more than numpy + OpenCV.
"""

from __future__ import annotations

import threading
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
    import numba

    module = globals()
    module["prange"] = numba.prange
    module["_popcount"] = _popcount_intrinsic()
    for name, (fn, parallel, fastmath) in _PENDING.items():
        module[name] = numba.njit(cache=True, parallel=parallel, fastmath=fastmath, nogil=True)(fn)
    _READY.append(True)


# ----------------------------------------------------------------------------------------------
# kernels
# ----------------------------------------------------------------------------------------------


@_kernel(parallel=True)
def _census(padded: np.ndarray, half_h: int, half_w: int) -> np.ndarray:
    """Census bit string per pixel: bit set where the neighbour is darker than the centre.

    ``padded`` has the image border replicated by (half_h, half_w); looping over x innermost
    keeps the loop vectorisable.
    """
    h = padded.shape[0] - 2 * half_h
    w = padded.shape[1] - 2 * half_w
    out = np.zeros((h, w), np.uint64)
    for y in prange(h):
        centre = padded[y + half_h, half_w:half_w + w]
        bits = out[y]
        for dy in range(2 * half_h + 1):
            for dx in range(2 * half_w + 1):
                if dy == half_h and dx == half_w:
                    continue
                row = padded[y + dy, dx:dx + w]
                for x in range(w):
                    bits[x] = (bits[x] << np.uint64(1)) | np.uint64(row[x] < centre[x])
    return out


def _popcount_intrinsic() -> Any:
    """``llvm.ctpop`` on uint64: one POPCNT instruction where the CPU has it (numba exposes none)."""
    from llvmlite import ir
    from numba import types
    from numba.core.extending import intrinsic

    @intrinsic
    def popcount(typingctx: Any, value: Any) -> Any:
        def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
            fn = builder.module.declare_intrinsic("llvm.ctpop", [ir.IntType(64)])
            return builder.call(fn, args)

        return types.uint64(types.uint64), codegen

    return popcount


def _popcount(v: np.uint64) -> np.uint64:
    """Placeholder; ``_kernels`` swaps in the ctpop intrinsic before compiling."""
    return np.uint64(bin(int(v)).count("1"))


@_kernel(parallel=True)
def _hamming_volume(cl: np.ndarray, cr: np.ndarray, min_d: int, vol: np.ndarray) -> None:
    """vol[y, x, k] = Hamming(census_left(x), census_right(x - min_d - k)).

    Right columns left of the image are clamped to column 0: the cost stays finite (it only feeds
    the aggregation) and the winner search later ignores those disparities. The unclamped part is
    a plain reversed run over the row, which LLVM vectorises.
    """
    h, w = cl.shape
    nd = vol.shape[2]
    for y in prange(h):
        for x in range(w):
            a = cl[y, x]
            kv = max(0, min(nd, x - min_d + 1))
            for k in range(kv):
                vol[y, x, k] = np.uint16(_popcount(a ^ cr[y, np.uint64(x - min_d - k)]))
            edge = np.uint16(_popcount(a ^ cr[y, 0]))
            for k in range(kv, nd):
                vol[y, x, k] = edge


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
def _start_path(cost: np.ndarray, buf: np.ndarray, acc: np.ndarray, first: bool) -> np.uint16:
    """First pixel of a path: L_r = C. ``first`` initialises S instead of adding (saves a memset)."""
    nd = cost.shape[0]
    m = np.uint16(0xFFFF)
    for k in range(nd):
        buf[k + 1] = cost[k]
        acc[k] = cost[k] if first else np.uint16(acc[k] + cost[k])
        m = min(m, cost[k])
    return m


@_kernel(parallel=True)
def _aggregate_rows(vol: np.ndarray, img: np.ndarray, acc: np.ndarray, p1: int, p2: int, gamma: float) -> None:
    """Left-to-right then right-to-left paths; rows are independent so they run in parallel.

    Runs first and stores S on the way out, so S needs no zeroing.
    """
    h, w, nd = vol.shape
    q1 = np.uint16(p1)
    for y in prange(h):
        a = np.full(nd + 2, _SENTINEL, np.uint16)
        b = np.full(nd + 2, _SENTINEL, np.uint16)
        m = _start_path(vol[y, 0], a, acc[y, 0], True)
        for x in range(1, w):
            q2 = _edge_p2(img[y, x], img[y, x - 1], p1, p2, gamma)
            m = _first_step(vol[y, x], a, m, b, acc[y, x], q1, q2)
            a, b = b, a
        m = _start_path(vol[y, w - 1], a, acc[y, w - 1], False)
        for x in range(w - 2, -1, -1):
            q2 = _edge_p2(img[y, x], img[y, x + 1], p1, p2, gamma)
            m = _path_step(vol[y, x], a, m, b, acc[y, x], q1, q2)
            a, b = b, a


@_kernel(parallel=True)
def _vertical_row(
    vol: np.ndarray, img: np.ndarray, acc: np.ndarray, y: int, step: int,
    prev: np.ndarray, prev_min: np.ndarray, cur: np.ndarray, cur_min: np.ndarray,
    p1: int, p2: int, gamma: float,
) -> None:
    """One row of the vertical (+ diagonal) paths, parallel over columns.

    Direction j uses dx = (0, -1, +1)[j]: the predecessor of (y, x) is (y - step, x - dx). Sweeping
    whole rows keeps memory access contiguous (walking single columns costs a TLB miss per step).
    """
    h, w, _ = vol.shape
    ndirs = prev.shape[0]
    q1 = np.uint16(p1)
    first_row = y == (0 if step == 1 else h - 1)
    for x in prange(w):
        for j in range(ndirs):
            px = x - (0 if j == 0 else (-1 if j == 1 else 1))
            if first_row or px < 0 or px >= w:
                cur_min[j, x] = _start_path(vol[y, x], cur[j, x], acc[y, x], False)
            else:
                q2 = _edge_p2(img[y, x], img[y - step, px], p1, p2, gamma)
                cur_min[j, x] = _path_step(vol[y, x], prev[j, px], prev_min[j, px], cur[j, x], acc[y, x], q1, q2)


@_kernel()
def _aggregate_columns(
    vol: np.ndarray, img: np.ndarray, acc: np.ndarray, p1: int, p2: int, gamma: float, ndirs: int
) -> None:
    """Top-down then bottom-up sweeps over rows (vertical, and diagonals when ``ndirs`` is 3)."""
    h, w, nd = vol.shape
    for step in (1, -1):
        prev = np.full((ndirs, w, nd + 2), _SENTINEL, np.uint16)
        cur = np.full((ndirs, w, nd + 2), _SENTINEL, np.uint16)
        prev_min = np.zeros((ndirs, w), np.uint16)
        cur_min = np.zeros((ndirs, w), np.uint16)
        y = 0 if step == 1 else h - 1
        for _ in range(h):
            _vertical_row(vol, img, acc, y, step, prev, prev_min, cur, cur_min, p1, p2, gamma)
            prev, cur = cur, prev
            prev_min, cur_min = cur_min, prev_min
            y += step


@_kernel()
def _first_step(
    cost: np.ndarray, prev: np.ndarray, prev_min: np.uint16, cur: np.ndarray, acc: np.ndarray,
    p1: np.uint16, p2: np.uint16,
) -> np.uint16:
    """``_path_step`` for the first path over S: stores instead of adding."""
    nd = cost.shape[0]
    jump = np.uint16(prev_min + p2)
    new_min = np.uint16(0xFFFF)
    for k in range(nd):
        best = min(min(prev[k + 1], jump), np.uint16(min(prev[k], prev[k + 2]) + p1))
        v = np.uint16(cost[k] + best - prev_min)
        cur[k + 1] = v
        new_min = min(new_min, v)
        acc[k] = v
    return new_min


@_kernel()
def _range_min(row: np.ndarray, lo: int | np.integer, hi: int | np.integer) -> np.uint16:
    """min(row[lo:hi]) as a vectorised reduction (0xFFFF when empty)."""
    m = np.uint16(0xFFFF)
    for k in range(max(lo, 0), hi):
        m = min(m, row[k])
    return m


@_kernel(parallel=True)
def _select(
    acc: np.ndarray, min_d: int, uniqueness: float, disp12: int, conf_gain: float, lr_penalty: float
) -> tuple[np.ndarray, np.ndarray]:
    """Winner-take-all on S for both views, uniqueness + left-right check, parabola, confidence.

    The right view's disparity at xr is argmin_k S[y, xr + min_d + k, k]: the same aggregated
    volume read along the diagonal, so no second matching pass is needed. Costs are packed as
    (S << 16) | k so that one min gives value and index (smallest k on ties) and both the left
    reduction and the right scatter-min vectorise.
    """
    h, w, nd = acc.shape
    disp = np.empty((h, w), np.float32)
    conf = np.zeros((h, w), np.float32)
    nan = np.float32(np.nan)
    for y in prange(h):
        right = np.full(w, 0xFFFFFFFF, np.uint32)
        left_k = np.full(w, -1, np.int32)
        ratio = np.zeros(w, np.float32)
        sub = np.zeros(w, np.float32)
        for x in range(w):
            kmax = min(nd, x - min_d + 1)  # right column x - min_d - k must be >= 0
            if kmax <= 0:
                continue
            row = acc[y, x]
            x0 = x - min_d
            packed = np.uint32(0xFFFFFFFF)
            for k in range(kmax):
                v = (np.uint32(row[k]) << np.uint32(16)) | np.uint32(k)
                packed = min(packed, v)
                xr = np.uint64(x0 - k)  # unsigned: no negative-index wraparound, so LLVM vectorises
                right[xr] = min(right[xr], v)
            bk = np.int64(packed & np.uint32(0xFFFF))
            if kmax < nd and bk == kmax - 1:
                continue  # best at the image edge: the true match may lie left of the right image
            best = np.float32(row[bk])
            second = np.float32(min(_range_min(row, 0, bk - 1), _range_min(row, bk + 2, kmax)))
            if second < 65535.0 and second * (np.float32(1.0) - uniqueness) < best:
                continue
            left_k[x] = bk
            ratio[x] = np.float32(1.0) if second >= 65535.0 else (second - best) / max(second, np.float32(1.0))
            if 0 < bk < kmax - 1:
                lo = np.float32(row[bk - 1])
                hi = np.float32(row[bk + 1])
                den = lo + hi - np.float32(2.0) * best
                if den > 0:
                    sub[x] = (lo - hi) / (np.float32(2.0) * den)
        for x in range(w):
            disp[y, x] = nan
            bk = left_k[x]
            if bk < 0:
                continue
            rk = np.int64(right[x - min_d - bk] & np.uint32(0xFFFF))
            diff = abs(rk - bk)
            if disp12 >= 0 and diff > disp12:
                continue
            disp[y, x] = np.float32(min_d + bk) + sub[x]
            c = min(np.float32(1.0), ratio[x] * np.float32(conf_gain))
            if diff > 0:
                c *= np.float32(lr_penalty)
            conf[y, x] = c
    return disp, conf


@_kernel(parallel=True)
def _close_gaps(
    disp: np.ndarray, invalid: np.float32, max_gap: int, tol: np.float32, occ_margin: int, border_margin: int
) -> np.ndarray:
    """Fill the hole runs of each row whose value the bounding measurements pin down.

    A run [x, e) bounded by a (left) and b (right): interpolated when short (<= ``max_gap``) and
    |a - b| <= ``tol``; given ``a`` when b - a > ``tol`` and e - x <= b - a + ``occ_margin`` (the
    background strip a foreground edge at e hides from the right camera is exactly b - a wide);
    a run from column 0 given ``b`` when e <= b + ``border_margin`` (no right pixel to match).
    Measured on the shared GT scenes these fills are right ~75-80 % of the time, about as often
    as the measured pixels bordering holes.
    """
    h, w = disp.shape
    out = disp.copy()
    for y in prange(h):
        x = 0
        while x < w:
            if disp[y, x] != invalid:
                x += 1
                continue
            e = x
            while e < w and disp[y, e] == invalid:
                e += 1
            n = e - x
            if e < w:
                b = disp[y, e]
                if x > 0:
                    a = disp[y, x - 1]
                    if n <= max_gap and abs(a - b) <= tol:
                        for i in range(x, e):
                            out[y, i] = a + (b - a) * np.float32(i - x + 1) / np.float32(n + 1)
                    elif occ_margin >= 0 and b - a > tol and n <= b - a + occ_margin:
                        for i in range(x, e):
                            out[y, i] = a
                elif border_margin >= 0 and e <= b + border_margin:
                    for i in range(x, e):
                        out[y, i] = b
            x = e
    return out


@_kernel(parallel=True)
def _median3(disp: np.ndarray, invalid: np.float32) -> np.ndarray:
    """3x3 median of each valid pixel; invalid neighbours (== ``invalid``) count as the centre value.

    Removes single-pixel outliers and WTA staircase noise without bleeding into holes. NaN is
    swapped for a finite sentinel by the caller so the kernel can use fastmath and a branch-free
    sorting network.
    """
    h, w = disp.shape
    out = disp.copy()
    for y in prange(1, h - 1):
        v = np.empty(9, np.float32)
        for x in range(1, w - 1):
            c = disp[y, x]
            if c == invalid:
                continue
            n = 0
            for yy in range(y - 1, y + 2):
                for xx in range(x - 1, x + 2):
                    d = disp[yy, xx]
                    v[n] = c if d == invalid else d
                    n += 1
            for i in range(9):  # odd-even transposition sort, 9 rounds: fixed, branch-free
                for j in range(i % 2, 8, 2):
                    lo = min(v[j], v[j + 1])
                    v[j + 1] = max(v[j], v[j + 1])
                    v[j] = lo
            out[y, x] = v[4]
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
    P1: float,
    P2: float,
    uniqueness_ratio: float,
    disp12_max_diff: int,
    census_size: tuple[int, int] = (7, 9),
    p2_gamma: float = 4.0,
    paths: int = 8,
    median: bool = True,
    speckle_size: int = 100,
    speckle_range: float = 1.0,
    conf_gain: float = 1.5,
    lr_penalty: float = 0.5,
    gap_max: int = 20,
    gap_tol: float = 2.0,
    occlusion_margin: int = 2,
    border_margin: int = 1,
    gap_confidence: float = 0.2,
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

    Gap closing (after the speckle filter, row by row; see ``_close_gaps``) fills only holes whose
    value the surrounding measurements pin down; the rest stay NaN for ``fill_holes``:

    * a run of at most ``gap_max`` holes whose two bounding values differ by at most ``gap_tol``
      is linearly interpolated (pixels the uniqueness / LR checks dropped inside a surface);
    * a run whose right neighbour is nearer by more than ``gap_tol`` and whose length is at most
      that disparity step + ``occlusion_margin`` is the strip a foreground edge hides from the
      right camera: it takes the left (background) value;
    * a run starting at column 0 no longer than the disparity bounding it + ``border_margin`` is
      the strip with no counterpart in the right image: it takes that value.

    Filled pixels get confidence ``gap_confidence``. ``gap_max`` 0 disables interpolation,
    a negative ``occlusion_margin`` / ``border_margin`` disables those fills.
    """
    _check_inputs(left, right, num_disparities, window_size, census_size, paths)
    _kernels()
    ch, cw = census_size
    cl = _census(_pad(left, ch // 2, cw // 2), ch // 2, cw // 2)
    cr = _census(_pad(right, ch // 2, cw // 2), ch // 2, cw // 2)
    vol, acc = _workspace(left.shape, int(num_disparities))
    _hamming_volume(cl, cr, int(min_disparity), vol)
    if window_size > 1:
        vol = _box_sum(vol, window_size)
    p1, p2, gamma = int(P1), int(P2), float(p2_gamma)
    _aggregate_rows(vol, left, acc, p1, p2, gamma)
    _aggregate_columns(vol, left, acc, p1, p2, gamma, 1 if paths == 4 else 3)
    disp, conf = _select(
        acc, int(min_disparity), uniqueness_ratio / 100.0, int(disp12_max_diff), conf_gain, lr_penalty
    )
    if median:
        sentinel = np.float32(-1e9)
        disp = _median3(np.where(np.isnan(disp), sentinel, disp), sentinel)
        disp[disp == sentinel] = np.nan
    if speckle_size > 0:
        disp = _remove_speckles(disp, speckle_size, speckle_range)
    conf[np.isnan(disp)] = 0.0
    if gap_max > 0 or occlusion_margin >= 0 or border_margin >= 0:
        holes = np.isnan(disp)
        sentinel = np.float32(-1e9)
        coded = np.where(holes, sentinel, disp).astype(np.float32)
        closed = _close_gaps(
            coded, sentinel, int(gap_max), np.float32(gap_tol), int(occlusion_margin), int(border_margin)
        )
        filled = holes & (closed != sentinel)
        disp = np.where(closed == sentinel, np.float32(np.nan), closed).astype(np.float32)
        conf[filled] = np.float32(gap_confidence)
    return disp, conf


def _pad(img: np.ndarray, half_h: int, half_w: int) -> np.ndarray:
    """Replicate the border so the census window never leaves the image."""
    return cv2.copyMakeBorder(img, half_h, half_h, half_w, half_w, cv2.BORDER_REPLICATE)


_local = threading.local()


def _workspace(shape: tuple[int, ...], nd: int) -> tuple[np.ndarray, np.ndarray]:
    """Cost and aggregate volumes, kept per thread and reused while the size stays the same.

    Two fresh 80 MB volumes per frame cost ~15 ms of page faults alone at 640x480x128.
    """
    key = (shape[0], shape[1], nd)
    if getattr(_local, "key", None) != key:
        _local.key = key
        _local.vol = np.empty(key, np.uint16)
        _local.acc = np.empty(key, np.uint16)
    return _local.vol, _local.acc


def _check_inputs(
    left: np.ndarray, right: np.ndarray, nd: int, window: int, census: tuple[int, int], paths: int
) -> None:
    """Refuse inputs the kernels would silently mis-handle."""
    if left.dtype != np.uint8 or right.dtype != np.uint8 or left.ndim != 2 or left.shape != right.shape:
        msg = (
            "census_sgm needs two uint8 grey images of one size, "
            f"got {left.dtype}{left.shape} and {right.dtype}{right.shape}"
        )
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


def _box_sum(vol: np.ndarray, window: int) -> np.ndarray:
    """Sum costs over a window x window support (edge replicated), with numpy slices.

    Not on the recommended path (window_size=1): it costs ~30 ms per pass at 640x480x128.
    """
    half = window // 2
    pad = np.pad(vol, ((half, half), (half, half), (0, 0)), mode="edge")
    h, w, _ = vol.shape
    rows = np.zeros((h, w + 2 * half, vol.shape[2]), np.uint16)
    for dy in range(window):
        rows += pad[dy:dy + h]
    out = np.zeros_like(vol)
    for dx in range(window):
        out += rows[:, dx:dx + w]
    return out


def _remove_speckles(disp: np.ndarray, size: int, max_diff: float) -> np.ndarray:
    """Drop small connected blobs that differ from their surroundings (OpenCV's speckle filter).

    Works on 1/16 px fixed point so neighbouring sub-pixel values stay connected.
    """
    invalid = np.int16(-32768)
    holes = np.isnan(disp)
    fixed = np.round(np.nan_to_num(disp, nan=0.0) * 16.0).astype(np.int16)
    fixed[holes] = invalid
    cv2.filterSpeckles(fixed, int(invalid), int(size), round(max_diff * 16))
    out = disp.copy()
    out[fixed == invalid] = np.nan
    return out


def fill_holes(
    disparity: np.ndarray, left: np.ndarray, *, radius: int = 3, sigma: float = 20.0, scanline: bool = True
) -> np.ndarray:
    """Fill every NaN so density is 1.0, favouring the background and following image edges.

    Holes are mostly occlusions beside a foreground edge, where the right value is the far
    (smaller) disparity of the occluded surface; a plain scanline fill drags the foreground in
    half the time. Step 1 looks for the nearest valid pixel along 8 directions and takes the
    second smallest of those values (Hirschmueller 2008: robust to one stray low value, still
    background-biased). Step 2 replaces each filled pixel by the weighted median of its
    (2 * radius + 1)^2 neighbourhood, weighted by intensity similarity to the pixel in ``left``,
    so fills follow object boundaries instead of cutting straight across them.
    """
    _kernels()
    disp = np.ascontiguousarray(disparity, dtype=np.float32)
    holes = np.isnan(disp)
    if not holes.any():
        return disp.copy()
    if holes.all():
        return np.zeros_like(disp)
    grey = left if left.ndim == 2 else cv2.cvtColor(left, cv2.COLOR_BGR2GRAY)
    grey = np.ascontiguousarray(grey, dtype=np.uint8)
    sentinel = np.float32(-1e9)
    coded = np.where(holes, sentinel, disp).astype(np.float32)
    filled = _fill_rows(coded, sentinel) if scanline else _fill_directions(coded, sentinel)
    if (filled == sentinel).any():  # whole rows without a value: fall back to the columns
        filled = _fill_rows(np.ascontiguousarray(filled.T), sentinel).T.copy()
    if radius > 0:
        filled = _weighted_median_fill(filled, coded, grey, sentinel, radius, np.float32(sigma))
    return filled


@_kernel(parallel=True)
def _fill_rows(disp: np.ndarray, invalid: np.float32) -> np.ndarray:
    """Each hole run takes the smaller of the valid values bounding it in its row (background)."""
    h, w = disp.shape
    out = disp.copy()
    for y in prange(h):
        x = 0
        while x < w:
            if disp[y, x] != invalid:
                x += 1
                continue
            end = x
            while end < w and disp[y, end] == invalid:
                end += 1
            lo = disp[y, x - 1] if x > 0 else invalid
            hi = disp[y, end] if end < w else invalid
            v = min(lo, hi) if lo != invalid and hi != invalid else max(lo, hi)
            for i in range(x, end):
                out[y, i] = v
            x = end
    return out


@_kernel(parallel=True)
def _fill_directions(disp: np.ndarray, invalid: np.float32) -> np.ndarray:
    """Second smallest of the nearest valid values along 8 directions (smallest if only one)."""
    h, w = disp.shape
    out = disp.copy()
    dys = (0, 0, 1, -1, 1, 1, -1, -1)
    dxs = (1, -1, 0, 0, 1, -1, 1, -1)
    for y in prange(h):
        for x in range(w):
            if disp[y, x] != invalid:
                continue
            lo1 = np.float32(np.inf)
            lo2 = np.float32(np.inf)
            for j in range(8):
                yy, xx = y + dys[j], x + dxs[j]
                while 0 <= yy < h and 0 <= xx < w:
                    v = disp[yy, xx]
                    if v != invalid:
                        if v < lo1:
                            lo2 = lo1
                            lo1 = v
                        elif v < lo2:
                            lo2 = v
                        break
                    yy += dys[j]
                    xx += dxs[j]
            out[y, x] = lo2 if lo2 < np.inf else lo1
    return out


@_kernel(parallel=True)
def _weighted_median_fill(
    filled: np.ndarray, coded: np.ndarray, img: np.ndarray, invalid: np.float32, radius: int, sigma: np.float32
) -> np.ndarray:
    """Intensity-weighted median over a window, applied only where ``coded`` was a hole."""
    h, w = filled.shape
    out = filled.copy()
    n = (2 * radius + 1) ** 2
    lut = np.exp(-np.arange(256).astype(np.float32) / sigma).astype(np.float32)
    for y in prange(h):
        vals = np.empty(n, np.float32)
        wts = np.empty(n, np.float32)
        for x in range(w):
            if coded[y, x] != invalid:
                continue
            c = np.int64(img[y, x])
            m = 0
            total = np.float32(0.0)
            for yy in range(max(y - radius, 0), min(y + radius + 1, h)):
                for xx in range(max(x - radius, 0), min(x + radius + 1, w)):
                    wt = lut[abs(np.int64(img[yy, xx]) - c)]
                    if coded[yy, xx] == invalid:
                        wt *= np.float32(0.5)  # guessed values count less than measured ones
                    vals[m] = filled[yy, xx]
                    wts[m] = wt
                    total += wt
                    m += 1
            order = np.argsort(vals[:m])
            half = total * np.float32(0.5)
            run = np.float32(0.0)
            for i in range(m):
                run += wts[order[i]]
                if run >= half:
                    out[y, x] = vals[order[i]]
                    break
    return out
