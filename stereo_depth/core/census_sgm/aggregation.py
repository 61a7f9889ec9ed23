"""Hamming costs, semi-global aggregation along 4, 5, 6 or 8 paths, and the winner selection it feeds.

Selection runs row by row inside the aggregation, as soon as the row's sums are complete, so the
two share this file (numba's cache sees only a function's own file; kernels that call each other
live together).
"""

from __future__ import annotations

import threading
from typing import Any

import numpy as np

from stereo_depth.core.census_sgm.registry import kernel as _kernel
from stereo_depth.core.census_sgm.registry import popcount_placeholder as _popcount

prange = range  # replaced by numba.prange before any kernel is compiled (registry.compile_all)

HOLE = np.float32(-1e9)  # stands for NaN in kernels that compare values (fastmath folds isnan away)
PATH_COST_MAX = 254  # largest matching cost + 2 x P2 the uint8 path costs hold (see ``cost_shift``)
STRIP_WARMUP = 48  # rows the lower strip runs before its first matched row (see ``_strips_select``)
NO_PATH_FROM_BELOW = np.zeros((0, 0, 0), np.uint8)  # ``_strips_select``'s ``up`` with 5 paths
BOTTOM_UP_STEP = 2  # the 6-path mode's path from below runs on every this-many rows and columns (``_bottom_up``)


@_kernel(inline=True)
def _hamming_pixel(cl: np.ndarray, cr_rev: np.ndarray, x: int, min_d: int, shift: int, vol: np.ndarray) -> None:
    """vol[x, k] = Hamming(census_left(x), census_right(x - min_d - k)) >> shift for one pixel of a row, in uint8.

    ``cr_rev`` is the right census row reversed (column w - 1 - xr), so that the run over k reads
    forwards: a plain loop LLVM vectorises without shuffles. Right columns left of the image are
    clamped to column 0: the cost stays finite (it only feeds the aggregation) and the winner
    search later ignores those disparities.
    """
    w = cl.shape[0]
    nd = vol.shape[1]
    bits = np.uint64(shift)
    a = cl[x]
    kv = max(0, min(nd, x - min_d + 1))
    first = np.uint64(w - 1 - x + min_d)  # cr_rev index of disparity min_d
    for k in range(kv):
        vol[x, k] = np.uint8(_popcount(a ^ cr_rev[first + np.uint64(k)]) >> bits)
    edge = np.uint8(_popcount(a ^ cr_rev[w - 1]) >> bits)
    for k in range(kv, nd):
        vol[x, k] = edge


@_kernel(parallel=True)
def _hamming_volume(cl: np.ndarray, cr_rev: np.ndarray, min_d: int, vol: np.ndarray) -> None:
    """The whole cost volume (``_hamming_pixel``, unshifted), for when it is box-summed before the sweeps."""
    for y in prange(cl.shape[0]):
        cl_row, cr_row, vol_row = cl[y], cr_rev[y], vol[y]
        for x in range(cl.shape[1]):
            _hamming_pixel(cl_row, cr_row, x, min_d, 0, vol_row)


@_kernel(inline=True)
def _recur(
    c: Any, lo: np.uint8, mid: np.uint8, hi: np.uint8, jump: np.uint8, prev_min: np.uint8, p1: np.uint8
) -> np.uint8:
    """One disparity of the SGM recurrence (Hirschmueller 2008), in uint8 arithmetic:

        L_r(p, d) = C(p, d) + min(L_r(p-r, d), L_r(p-r, d+-1) + P1, min_k L_r(p-r, k) + P2) - min_k L_r(p-r, k)

    with lo/mid/hi = L_r(p-r, d-1 / d / d+1) and jump = min_k L_r(p-r, k) + P2. Branch-free, so
    loops over d calling it vectorise (32 lanes a 256-bit vector). ``cost_shift`` keeps every term
    below 256: L_r <= C + P2, jump <= max C + 2 P2, and the sentinel + P1 = 255.
    """
    return np.uint8(c + min(min(mid, jump), np.uint8(min(lo, hi) + p1)) - prev_min)


@_kernel(inline=True)
def _path(
    cost: np.ndarray,  # (w, nd) matching costs C of the row
    x: int,  # p's column
    buf: np.ndarray,  # flat uint8 path buffers, each nd + 2 long with sentinels at both ends
    i0: int,  # L_r(p - r) is buf[i0 : i0 + nd + 2]
    o0: int,  # out: L_r(p) goes to buf[o0 + 1 : o0 + nd + 1]
    prev_min: np.uint8,  # min_d L_r(p - r)
    p1: np.uint8,
    p2: np.uint8,
    nd: int,
) -> np.uint8:
    """Advance one path by one pixel; returns min_d L_r(p).

    Shaped for LLVM's vectoriser and for a short per-call set-up, since a call is only a few
    vector steps: branch-free, uint8 only (32 lanes a 256-bit vector; S is summed separately by
    ``_add_paths``), the path buffers flat with unsigned offsets (no strides, no negative-index
    wraparound). Cost stays a 2-D row indexed by x: flat offsets for it made the right-to-left
    sweep ~10x slower. A path's first pixel passes a zero predecessor (sentinel ends, minimum 0):
    the recurrence then gives L_r = C exactly, so path starts need no code of their own.
    """
    jump = np.uint8(prev_min + p2)
    new_min = np.uint8(0xFF)
    for k in range(nd):
        i = np.uint64(i0 + k)
        v = _recur(cost[x, k], buf[i], buf[i + np.uint64(1)], buf[i + np.uint64(2)], jump, prev_min, p1)
        buf[np.uint64(o0 + 1 + k)] = v
        new_min = min(new_min, v)
    return new_min


@_kernel(inline=True)
def _add_paths(
    acc: np.ndarray,  # (w, nd) uint16 S of the row: S(p) becomes (S(p) & keep) + the paths' L_r(p)
    x: int,
    keep: np.uint16,  # 0 stores the sum in S (the sweep that comes first), 0xFFFF adds it
    line: np.ndarray,  # the horizontal path's L_r(p) is line[h0 + 1 : h0 + nd + 1]
    h0: int,
    state: np.ndarray,  # the vertical / diagonal paths' L_r(p) are state[o0 + j * step + 1 ...], j < ndirs
    o0: int,
    step: int,
    ndirs: int,
    nd: int,
) -> None:
    """S(p) for one pixel and sweep: one read-modify-write of the uint16 row per pixel, not one per path."""
    for k in range(nd):
        total = np.uint16(line[np.uint64(h0 + 1 + k)]) + np.uint16(state[np.uint64(o0 + 1 + k)])
        acc[x, k] = np.uint16((acc[x, k] & keep) + total)
    if ndirs == 3:
        for k in range(nd):
            a = np.uint16(state[np.uint64(o0 + step + 1 + k)])
            b = np.uint16(state[np.uint64(o0 + 2 * step + 1 + k)])
            acc[x, k] = np.uint16(acc[x, k] + a + b)


@_kernel(inline=True)
def _store_paths(
    acc: np.ndarray,  # (w, nd) uint16 S of the row: S(p) becomes the four (five) paths' sum
    x: int,
    line: np.ndarray,  # the left-to-right path's L_r(p) is line[h0 + 1 : h0 + nd + 1]
    h0: int,
    state: np.ndarray,  # the vertical / diagonal paths' L_r(p) are state[o0 + j * step + 1 ...], j < 3
    o0: int,
    step: int,
    up: np.ndarray,  # with 6 paths, the path from below at p is up[u0 + 1 : u0 + nd + 1] (``_bottom_up``)
    u0: int,  # < 0 with 5 paths
) -> None:
    """S(p) = the paths a row's left-to-right pass carries: one write of the uint16 row per pixel."""
    if u0 < 0:
        for k in range(acc.shape[1]):
            a = np.uint16(line[np.uint64(h0 + 1 + k)]) + np.uint16(state[np.uint64(o0 + 1 + k)])
            b = np.uint16(state[np.uint64(o0 + step + 1 + k)]) + np.uint16(state[np.uint64(o0 + 2 * step + 1 + k)])
            acc[x, k] = np.uint16(a + b)
    else:
        for k in range(acc.shape[1]):
            a = np.uint16(line[np.uint64(h0 + 1 + k)]) + np.uint16(state[np.uint64(o0 + 1 + k)])
            b = np.uint16(state[np.uint64(o0 + step + 1 + k)]) + np.uint16(state[np.uint64(o0 + 2 * step + 1 + k)])
            acc[x, k] = np.uint16(a + b + np.uint16(up[np.uint64(u0 + 1 + k)]))


@_kernel(inline=True)
def _add_line(acc: np.ndarray, x: int, line: np.ndarray, h0: int) -> None:
    """S(p) += the right-to-left path's L_r(p) (line[h0 + 1 : h0 + nd + 1])."""
    for k in range(acc.shape[1]):
        acc[x, k] = np.uint16(acc[x, k] + np.uint16(line[np.uint64(h0 + 1 + k)]))


@_kernel()
def _edge_p2(a: np.uint8, b: np.uint8, p1: int, p2: int, gamma: float) -> np.uint16:
    """P2 divided by the intensity step between neighbours: depth jumps are cheap across edges."""
    g = abs(np.int32(a) - np.int32(b))
    return np.uint16(max(p1 + 1, int(p2 / (1.0 + g / gamma))))


@_kernel()
def _p2_table(sgm: tuple[int, int, float, int]) -> np.ndarray:
    """``_edge_p2`` for every intensity step 0..255 as uint8 (P2 fits: ``cost_shift``), so the paths do a
    lookup instead of two divisions; ``sgm`` is (P1, P2, p2_gamma, paths)."""
    table = np.empty(256, np.uint8)
    for g in range(256):
        table[g] = np.uint8(_edge_p2(np.uint8(g), np.uint8(0), sgm[0], sgm[1], sgm[2]))
    return table


@_kernel(inline=True)
def _sweep(
    vol: np.ndarray,
    census: tuple[np.ndarray, np.ndarray] | None,
    shift: int,
    img: np.ndarray,
    acc: np.ndarray,
    p2_of: np.ndarray,
    p1: int,
    bufs: np.ndarray,
    mins: np.ndarray,
    y0: int,
    y1: int,
    sy: int,
    finish: bool,
    select: tuple[int, float, int, float, float],
    disp: np.ndarray,
    conf: np.ndarray,
) -> None:
    """Rows y0, y0 + sy, ... (up to y1) of one vertical sweep: 2 or 4 of the 8 SGM paths.

    A top-down sweep (sy = 1) runs the left-to-right path and the paths coming from (y-1, x),
    (y-1, x+1), (y-1, x-1); a bottom-up sweep (sy = -1) the right-to-left path and those from
    (y+1, x), (y+1, x+1), (y+1, x-1). With one direction in ``bufs`` (4-path mode), only the
    horizontal and vertical paths.

    ``bufs[y & 1, j]`` holds row y's L_r for vertical / diagonal direction j, one slot per
    column in sweep order (slot i + 1 for the i-th column visited, so memory is walked forwards
    in both sweeps) plus a padding slot per side that stays zero: the zero predecessor that
    starts a path at the border. ``mins`` holds their minima. Both persist between calls, so a
    sweep can stop at the middle row and resume. With ``finish`` False the paths store S,
    otherwise they add to it: S of the row is then complete (the opposite sweep already passed
    it), and the row is matched at once while it is still in cache. With ``census`` (left, right
    census images) the storing rows fill ``vol[y, x]`` just before the paths of pixel x read it
    (still in L1), and the other sweep reads it back; every cost is stored exactly once.
    """
    h, w, nd = vol.shape
    ndirs = bufs.shape[1]
    n2 = nd + 2
    span = w + 2  # buffers per direction and row
    state = bufs.reshape(bufs.size)
    line = np.full(3 * n2, bufs[0, 0, 0, 0], np.uint8)  # horizontal path: zero start, then a ping-pong pair
    line[1 : nd + 1] = 0
    scratch = _selection_scratch(w)
    q1 = np.uint8(p1)
    no_census = np.empty(0, np.uint64)
    keep = np.uint16(0xFFFF) if finish else np.uint16(0)
    x0 = 0 if sy == 1 else w - 1
    for y in range(y0, y1, sy):
        cost, s_row = vol[y], acc[y]
        fill = census is not None and not finish
        cl_row, cr_row = (census[0][y], census[1][y]) if census is not None else (no_census, no_census)
        cur_min, prev_min = mins[y & 1], mins[(y & 1) ^ 1]
        cur0 = (y & 1) * ndirs * span  # index of row y's first buffer; row y - sy's is prev0
        prev0 = ((y & 1) ^ 1) * ndirs * span
        yp = min(max(y - sy, 0), h - 1)  # row of the predecessors (any row on the first: prev is zero)
        h_min = np.uint8(0)
        for i in range(w):
            x = x0 + i * sy
            s = i + 1
            if fill:
                _hamming_pixel(cl_row, cr_row, x, select[0], shift, cost)
            c = np.int64(img[y, x])
            h_p2 = p2_of[abs(c - np.int64(img[y, min(max(x - sy, 0), w - 1)]))]
            h_in = 0 if i == 0 else 2 - (i & 1)
            h_out = (1 + (i & 1)) * n2
            h_min = _path(cost, x, line, h_in * n2, h_out, h_min, q1, h_p2, nd)
            v_p2 = p2_of[abs(c - np.int64(img[yp, x]))]
            cur_min[0, s] = _path(cost, x, state, (prev0 + s) * n2, (cur0 + s) * n2, prev_min[0, s], q1, v_p2, nd)
            if ndirs == 3:
                sa, sb = s + sy, s - sy  # slots of columns x + 1 and x - 1
                a_p2 = p2_of[abs(c - np.int64(img[yp, min(x + 1, w - 1)]))]
                b_p2 = p2_of[abs(c - np.int64(img[yp, max(x - 1, 0)]))]
                ia, oa = (prev0 + span + sa) * n2, (cur0 + span + s) * n2
                cur_min[1, s] = _path(cost, x, state, ia, oa, prev_min[1, sa], q1, a_p2, nd)
                ib, ob = (prev0 + 2 * span + sb) * n2, (cur0 + 2 * span + s) * n2
                cur_min[2, s] = _path(cost, x, state, ib, ob, prev_min[2, sb], q1, b_p2, nd)
            _add_paths(s_row, x, keep, line, h_out, state, (cur0 + s) * n2, span * n2, ndirs, nd)
        if finish:
            _select_row(s_row, select, disp[y], conf[y], scratch)


@_kernel(inline=True)
def _strip(
    vol: np.ndarray,
    census: tuple[np.ndarray, np.ndarray] | None,
    shift: int,
    img: np.ndarray,
    p2_of: np.ndarray,
    p1: int,
    rows: tuple[int, int, int],
    select: tuple[int, float, int, float, float],
    disp: np.ndarray,
    conf: np.ndarray,
    up: np.ndarray,
    nd: int,
) -> None:
    """Rows start..end - 1 of ``rows`` (start, first, end), top-down along five paths; those from ``first`` matched.

    Per row: a left-to-right pass computes the costs (``_hamming_pixel`` from ``census``, else
    reads ``vol[y]``) and runs the left-to-right path and the three from the row above ((y-1, x),
    (y-1, x+1), (y-1, x-1)), storing their sum S (with the path from below, ``up`` from
    ``_bottom_up``, when it is not empty: 6 paths); a right-to-left pass adds the fifth path; the
    row is then matched. Everything a row touches (its costs, S, the path rows: ~0.7 MB at
    640 x 128) stays in L2, and nothing of image size is written but the output.

    ``bufs[y & 1, j]`` holds row y's L_r for vertical / diagonal direction j, slot x + 1 for
    column x, plus a padding slot per side that stays zero: the zero predecessor that starts a
    path at the border, as the all-zero previous row does at ``start`` (L_r = C exactly there,
    so path starts need no code of their own). ``mins`` holds their minima.

    ``nd`` is the disparity count, ``vol.shape[2]``. A caller that passes it as a literal (64, 128)
    gets a copy of this kernel with a constant count: LLVM then knows the trip count of the
    per-pixel loops over the disparities and drops their run-time set-up (trip-count, remainder and
    overlap checks), which costs about as much as a short loop itself (the quality profile's match
    0.88-0.91x at 640x480x128 on a Zen 1, bit-identical).
    """
    start, first, end = rows
    h, w = img.shape
    n2 = nd + 2
    span = w + 2  # buffers per direction and row
    bufs = np.zeros((2, 3, span, n2), np.uint8)  # (row parity, direction, slot, d)
    bufs[:, :, :, 0] = 255 - p1  # above every path cost, and + P1 still fits
    bufs[:, :, :, nd + 1] = 255 - p1
    mins = np.zeros((2, 3, span), np.uint8)
    state = bufs.reshape(bufs.size)
    line = np.full(3 * n2, np.uint8(255 - p1), np.uint8)  # horizontal paths: zero start, then a ping-pong pair
    line[1 : nd + 1] = 0
    row_cost = np.empty((w, nd), np.uint8)
    s_row = np.empty((w, nd), np.uint16)
    scratch = _selection_scratch(w)
    q1 = np.uint8(p1)
    no_census = np.empty(0, np.uint64)
    up_cols = up.shape[1]
    up_flat = up.reshape(up.size)
    for y in range(start, end):
        up_row = ((h - 1 - y) // BOTTOM_UP_STEP + 1) * up_cols  # the computed row at or below y
        cost = row_cost if census is not None else vol[y]
        cl_row, cr_row = (census[0][y], census[1][y]) if census is not None else (no_census, no_census)
        cur_min, prev_min = mins[y & 1], mins[(y & 1) ^ 1]
        cur0 = (y & 1) * 3 * span  # index of row y's first buffer; row y - 1's is prev0
        prev0 = ((y & 1) ^ 1) * 3 * span
        yp = max(y - 1, 0)  # row of the predecessors (any row at ``start``: prev is zero)
        h_min = np.uint8(0)
        for x in range(w):
            s = x + 1
            if census is not None:
                _hamming_pixel(cl_row, cr_row, x, select[0], shift, cost)
            c = np.int64(img[y, x])
            h_p2 = p2_of[abs(c - np.int64(img[y, max(x - 1, 0)]))]
            h_in = 0 if x == 0 else 2 - (x & 1)
            h_out = (1 + (x & 1)) * n2
            h_min = _path(cost, x, line, h_in * n2, h_out, h_min, q1, h_p2, nd)
            v_p2 = p2_of[abs(c - np.int64(img[yp, x]))]
            cur_min[0, s] = _path(cost, x, state, (prev0 + s) * n2, (cur0 + s) * n2, prev_min[0, s], q1, v_p2, nd)
            a_p2 = p2_of[abs(c - np.int64(img[yp, min(x + 1, w - 1)]))]
            b_p2 = p2_of[abs(c - np.int64(img[yp, max(x - 1, 0)]))]
            ia, oa = (prev0 + span + s + 1) * n2, (cur0 + span + s) * n2
            cur_min[1, s] = _path(cost, x, state, ia, oa, prev_min[1, s + 1], q1, a_p2, nd)
            ib, ob = (prev0 + 2 * span + s - 1) * n2, (cur0 + 2 * span + s) * n2
            cur_min[2, s] = _path(cost, x, state, ib, ob, prev_min[2, s - 1], q1, b_p2, nd)
            u0 = (up_row + x // BOTTOM_UP_STEP) * n2 if up.size else -1  # the computed column at or left of x
            _store_paths(s_row, x, line, h_out, state, (cur0 + s) * n2, span * n2, up_flat, u0)
        h_min = np.uint8(0)
        for i in range(w):
            x = w - 1 - i
            h_p2 = p2_of[abs(np.int64(img[y, x]) - np.int64(img[y, min(x + 1, w - 1)]))]
            h_in = 0 if i == 0 else 2 - (i & 1)
            h_out = (1 + (i & 1)) * n2
            h_min = _path(cost, x, line, h_in * n2, h_out, h_min, q1, h_p2, nd)
            _add_line(s_row, x, line, h_out)
        if y >= first:
            _select_row(s_row, select, disp[y], conf[y], scratch)


@_kernel(inline=True)
def _selection_scratch(w: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``_select_row``'s scratch rows of width w: the right view's best cost and disparity, the left
    view's winner, the uniqueness ratio and the sub-pixel offset; allocated once per sweep or strip."""
    return (
        np.empty(w, np.uint16),
        np.empty(w, np.uint16),
        np.empty(w, np.int32),
        np.empty(w, np.float32),
        np.empty(w, np.float32),
    )


@_kernel()
def _select_row(
    s_row: np.ndarray,
    select: tuple[int, float, int, float, float],
    disp: np.ndarray,
    conf: np.ndarray,
    scratch: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
) -> None:
    """Winner-take-all on one row of S for both views, uniqueness + left-right check, parabola, confidence.

    ``select`` is (min_d, uniqueness, disp12, conf_gain, lr_penalty); ``disp`` / ``conf`` are the
    output row (``HOLE`` / 0 on entry), ``scratch`` the rows of ``_selection_scratch``.
    The right view's disparity at xr is argmin_k S[xr + min_d + k, k]: the same aggregated row
    read along the diagonal, so no second matching pass is needed. For each x the right view's
    best cost and disparity so far (``right_cost``, ``right_k``) are updated for every k in one
    branch-free uint16 pass (16 lanes a 256-bit vector), which also gives the left minimum;
    they are stored mirrored (xr at w - 1 - xr) so that pass runs forwards. Ties go to the
    smallest disparity in both views (a strict < along increasing k). ``s_row`` is spent afterwards:
    the three sums around each winner are overwritten so the rival search is a plain minimum.
    """
    right_cost, right_k, left_k, ratio, sub = scratch
    min_d, uniqueness, disp12, conf_gain, lr_penalty = select
    w, nd = s_row.shape
    right_cost[:] = 0xFFFF
    right_k[:] = 0xFFFF
    for x in range(w):
        left_k[x] = -1
        kmax = min(nd, x - min_d + 1)  # right column x - min_d - k must be >= 0
        if kmax <= 0:
            continue
        mirror = np.uint64(w - 1 - (x - min_d))  # unsigned: no negative-index wraparound, so LLVM vectorises
        least = np.uint16(0xFFFF)
        for k in range(kmax):
            v = s_row[x, k]
            least = min(least, v)
            xr = mirror + np.uint64(k)
            old_cost, old_k = right_cost[xr], right_k[xr]  # both loaded first: a select, not a branch
            right_k[xr] = np.uint16(k) if v < old_cost else old_k
            right_cost[xr] = min(old_cost, v)
        first = np.uint16(0xFFFF)
        for k in range(kmax):
            first = min(first, np.uint16(k) if s_row[x, k] == least else np.uint16(0xFFFF))
        bk = int(first)
        if kmax < nd and bk == kmax - 1:
            continue  # best at the image edge: the true match may lie left of the right image
        best = np.float32(s_row[x, bk])
        lo = np.float32(s_row[x, max(bk - 1, 0)])  # the parabola's neighbours (used inside the row only)
        hi = np.float32(s_row[x, min(bk + 1, kmax - 1)])
        # Best outside bk-1..bk+1: those three are overwritten in S (read for the last time here), so
        # the search is a plain minimum, 16 lanes a 256-bit vector with no per-disparity index.
        for k in range(max(bk - 1, 0), min(bk + 2, kmax)):
            s_row[x, k] = 0xFFFF
        rival = np.uint16(0xFFFF)
        for k in range(kmax):
            rival = min(rival, s_row[x, k])
        second = np.float32(rival)
        if second < 65535.0 and second * (np.float32(1.0) - uniqueness) < best:
            continue
        left_k[x] = bk
        ratio[x] = np.float32(1.0) if second >= 65535.0 else (second - best) / max(second, np.float32(1.0))
        sub[x] = 0.0
        if 0 < bk < kmax - 1:
            den = lo + hi - np.float32(2.0) * best
            if den > 0:
                sub[x] = (lo - hi) / (np.float32(2.0) * den)
    for x in range(w):
        bk = left_k[x]
        if bk < 0:
            continue
        rk = np.int64(right_k[w - 1 - (x - min_d - bk)])
        diff = abs(rk - bk)
        if disp12 >= 0 and diff > disp12:
            continue
        disp[x] = np.float32(min_d + bk) + sub[x]
        c = min(np.float32(1.0), ratio[x] * np.float32(conf_gain))
        if diff > 0:
            c *= np.float32(lr_penalty)
        conf[x] = c


@_kernel(parallel=True)
def _aggregate_select(
    vol: np.ndarray,
    census: tuple[np.ndarray, np.ndarray] | None,
    shift: int,
    img: np.ndarray,
    acc: np.ndarray,
    sgm: tuple[int, int, float, int],
    select: tuple[int, float, int, float, float],
) -> tuple[np.ndarray, np.ndarray]:
    """8- or 4-path SGM aggregation into ``acc`` and matching: returns (disparity, confidence).

    Two sweeps run side by side, one top-down and one bottom-up, each carrying half of the paths
    (``_sweep``). Until they meet in the middle row each stores S on its own half of the image;
    after that each adds its paths to the half the other one stored, which completes S row by
    row, and matches the row at once. The storing sweeps also compute the costs from ``census``
    (``_hamming_pixel``) just before using them (``census`` None: ``vol`` holds them already). So
    the cost volume is written once and read back once, S written and read once, with no second
    volume, no zeroing, and two parallel launches per frame (a parallel launch per row, parallel
    over columns, cost ~5x more at 640x480). The price: this stage uses two cores at most.
    ``sgm`` is (P1, P2, p2_gamma, paths).
    """
    h, p1 = vol.shape[0], sgm[0]
    p2_of, bufs, mins, disp, conf = _sweep_state(vol, sgm)
    for finish in (False, True):
        for t in prange(2):
            y0, y1, sy = _sweep_rows(h, t, finish)
            _sweep(vol, census, shift, img, acc, p2_of, p1, bufs[t], mins[t], y0, y1, sy, finish, select, disp, conf)
    return disp, conf


@_kernel(inline=True)
def _sweep_state(
    vol: np.ndarray, sgm: tuple[int, int, float, int]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """What the two sweeps share: the P2 table, path buffers and minima per sweep, the output rows."""
    h, w, nd = vol.shape
    p1, paths = sgm[0], sgm[3]
    ndirs = 3 if paths == 8 else 1
    p2_of = _p2_table(sgm)
    bufs = np.zeros((2, 2, ndirs, w + 2, nd + 2), np.uint8)  # (sweep, row parity, direction, slot, d)
    bufs[:, :, :, :, 0] = 255 - p1  # above every path cost, and + P1 still fits
    bufs[:, :, :, :, nd + 1] = 255 - p1
    mins = np.zeros((2, 2, ndirs, w + 2), np.uint8)
    return p2_of, bufs, mins, np.full((h, w), HOLE, np.float32), np.zeros((h, w), np.float32)


@_kernel(inline=True)
def _sweep_rows(h: int, t: int, finish: bool) -> tuple[int, int, int]:
    """(first row, end row, step) of sweep t (0 top-down, 1 bottom-up): up to the middle row, then past it."""
    mid = h // 2
    if t == 0:
        return (mid, h, 1) if finish else (0, mid, 1)
    return (mid - 1, -1, -1) if finish else (h - 1, mid - 1, -1)


@_kernel(parallel=True)
def _bottom_up(
    vol: np.ndarray,
    census: tuple[np.ndarray, np.ndarray] | None,
    shift: int,
    img: np.ndarray,
    sgm: tuple[int, int, float, int],
    min_d: int,
) -> np.ndarray:
    """The 6-path mode's path from below, coarse: L_r along (y + 2, x) on every other row and column.

    Rows h - 1, h - 3, ... and columns 0, 2, ... (``BOTTOM_UP_STEP``): a quarter of one path's
    costs and updates. The row between two computed rows takes the one below it, the column
    between two computed columns the one left of it (``_strip`` reads it so). Returns
    (rows + 1, columns, nd + 2) uint8 path costs with the sentinels of ``_path`` at both ends of
    each; entry 0 is the zero predecessor that starts the path at the bottom row. Its information
    from below is what the five paths from above and the side lack: over the 38 ground-truth
    scenes it brings them within 0.0011 of 8 paths in bad-1, bad-2, bad-2 of estimated pixels and
    density (at every row and column, bad-1 within 0.0005 of 8 paths, at 4x the cost). Two column
    halves side by side; a vertical path stays in its column, so they need nothing of each other.
    """
    h, w, nd = vol.shape
    p1 = sgm[0]
    n2 = nd + 2
    step = BOTTOM_UP_STEP
    rows, cols = (h + step - 1) // step, (w + step - 1) // step
    up = np.empty((rows + 1, cols, n2), np.uint8)
    up[0] = 0
    up[:, :, 0] = 255 - p1  # above every path cost, and + P1 still fits
    up[:, :, nd + 1] = 255 - p1
    flat = up.reshape(up.size)
    mins = np.zeros(cols, np.uint8)
    p2_of = _p2_table(sgm)
    q1 = np.uint8(p1)
    half = (cols + 1) // 2
    for t in prange(2):
        row_cost = np.empty((w, nd), np.uint8)
        for j in range(rows):
            y = h - 1 - j * step
            below = min(y + step, h - 1)  # any row at j = 0: the predecessor is zero
            cost = row_cost if census is not None else vol[y]
            for xc in range(t * half, min(cols, (t + 1) * half)):
                x = xc * step
                if census is not None:
                    _hamming_pixel(census[0][y], census[1][y], x, min_d, shift, cost)
                p2x = p2_of[abs(np.int64(img[y, x]) - np.int64(img[below, x]))]
                i0, o0 = (j * cols + xc) * n2, ((j + 1) * cols + xc) * n2
                mins[xc] = _path(cost, x, flat, i0, o0, mins[xc], q1, p2x, nd)
    return up


@_kernel(parallel=True)
def _strips_select(
    vol: np.ndarray,
    census: tuple[np.ndarray, np.ndarray],
    shift: int,
    img: np.ndarray,
    sgm: tuple[int, int, float, int],
    select: tuple[int, float, int, float, float],
    up: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """5- or 6-path SGM aggregation and matching in two row strips side by side: returns (disparity, confidence).

    The five paths all come from above or from the side (``_strip``), so one top-down pass per
    strip completes S row by row and matches each row while it is in cache: no cost or sum volume.
    With 6 paths, ``up`` holds the coarse path from below (``_bottom_up``), added into S; with 5 it
    is empty. The lower strip starts ``STRIP_WARMUP`` rows above its first matched row, so its paths from
    above carry that much context into it (SGM paths forget their start within a few dozen rows);
    the split row gives both strips as many rows. Two strips whatever the thread count, so the
    result does not depend on it; this stage uses two cores at most.
    """
    h, w, nd = vol.shape
    p1 = sgm[0]
    p2_of, disp, conf = _strips_state(h, w, sgm)
    for t in prange(2):
        rows = _strip_rows(h, t)
        # the common counts as literals: each call pastes in a copy of ``_strip`` with a constant count
        if nd == 64:
            _strip(vol, census, shift, img, p2_of, p1, rows, select, disp, conf, up, 64)
        elif nd == 128:
            _strip(vol, census, shift, img, p2_of, p1, rows, select, disp, conf, up, 128)
        else:
            _strip(vol, census, shift, img, p2_of, p1, rows, select, disp, conf, up, nd)
    return disp, conf


@_kernel(parallel=True)
def _strips_select_volume(
    vol: np.ndarray,
    img: np.ndarray,
    sgm: tuple[int, int, float, int],
    select: tuple[int, float, int, float, float],
    up: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """``_strips_select`` on a cost volume computed beforehand (window_size > 1, box-summed and shifted).

    A kernel of its own with one copy of ``_strip`` for any count: no profile sums a window, and the
    constant-count copies take most of numba's compile time at install.
    """
    h, w, nd = vol.shape
    p2_of, disp, conf = _strips_state(h, w, sgm)
    for t in prange(2):
        _strip(vol, None, 0, img, p2_of, sgm[0], _strip_rows(h, t), select, disp, conf, up, nd)
    return disp, conf


@_kernel(inline=True)
def _strips_state(h: int, w: int, sgm: tuple[int, int, float, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What the two strips share: the P2 table and the output images."""
    p2_of = _p2_table(sgm)
    return p2_of, np.full((h, w), HOLE, np.float32), np.zeros((h, w), np.float32)


@_kernel(inline=True)
def _strip_rows(h: int, t: int) -> tuple[int, int, int]:
    """Strip t's (first row aggregated, first row matched, end row): as many matched rows as the other."""
    warmup = min(STRIP_WARMUP, h // 2)
    split = (h + warmup) // 2
    return (0, 0, split) if t == 0 else (split - warmup, split, h)


_local = threading.local()


def _workspace(shape: tuple[int, ...], nd: int) -> tuple[np.ndarray, np.ndarray]:
    """Cost and aggregate volumes, kept per thread and reused while the size stays the same.

    Fresh volumes per frame (40 + 80 MB at 640x480x128) cost ~10 ms of page faults alone.
    """
    key = (shape[0], shape[1], nd)
    if getattr(_local, "key", None) != key:
        _local.key = key
        _local.vol = np.empty(key, np.uint8)
        _local.acc = np.empty(key, np.uint16)
    return _local.vol, _local.acc


def cost_shift(census_bits: int, window: int, p1: float, p2: float) -> tuple[int, int, int]:
    """(shift, P1, P2): the right shift of matching costs, and the penalties shifted alike, that fit 8 bits.

    Path costs are uint8 (twice the SIMD lanes of uint16, half the memory traffic): with
    max C + 2 P2 <= PATH_COST_MAX nothing can wrap (see ``_recur``). Costs and penalties shift
    together, so their ratios stay; the quality profile (census 62 bits, P2 200) shifts by 1, which
    measured no worse over the 38 ground-truth scenes than 16-bit costs. StereoParams refuses a P2
    so large that the shift would leave fewer than 4 cost levels per pixel (P2 2000 at window 1 still
    gave bad-2 0.13 on Cones, against 0.12 at the profile's 200).
    """
    largest = census_bits * window * window
    shift = 0
    while True:
        q1 = round(p1 / (1 << shift))
        q2 = max(q1 + 1, round(p2 / (1 << shift)))
        if (largest >> shift) + 2 * q2 <= PATH_COST_MAX:
            return shift, q1, q2
        shift += 1


def _box_sum(vol: np.ndarray, window: int, shift: int) -> np.ndarray:
    """Sum costs over a window x window support (edge replicated), shifted right by ``shift``, as uint8.

    Running sums in uint32 (a window of 255 sums 4 M bits); not on the recommended path
    (window_size=1).
    """
    half = window // 2
    h, w, _ = vol.shape
    pad = np.pad(vol, ((half + 1, half), (half + 1, half), (0, 0)), mode="edge").astype(np.uint32)
    pad[0] = 0
    pad[:, 0] = 0
    np.cumsum(pad, axis=0, out=pad)
    rows = pad[window:] - pad[:h]  # uint32 wraps consistently: differences of running sums stay exact
    np.cumsum(rows, axis=1, out=rows)
    sums = rows[:, window:] - rows[:, :w]
    return (sums >> np.uint32(shift)).astype(np.uint8)
