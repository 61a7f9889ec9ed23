"""A plain numpy census + semi-global matcher: the definition the numba core must reproduce.

Written for clarity, not speed (a path at a time, a pixel or a row at a time, integers wide enough
that nothing wraps), so the kernels' tricks (8-bit path costs, sweeps that meet in the middle, the
right view read off the left's aggregated row, mirrored scratch rows, row strips) can be checked against it.
It follows ``census_sgm``'s documented rules (restated here, nothing imported from the code it checks):
border-replicated 7x9 census, Hamming costs shifted as ``cost_shift`` documents, costs of right
columns left of the image clamped to column 0, the SGM recurrence with P2 divided by the intensity
step to the predecessor, paths that start with L = C where the predecessor is outside the image,
winner-take-all with ties to the smaller disparity, uniqueness against the best cost more than one
disparity away, the left-right check, parabola sub-pixel and the confidence margin.
"""

from __future__ import annotations

import numpy as np

PATH_COST_MAX = 254  # uint8 path costs: the largest matching cost plus 2 x P2 must fit


def cost_shift(census_bits: int, p1: float, p2: float) -> tuple[int, int, int]:
    """The documented 8-bit scaling: the smallest right shift s with (bits >> s) + 2 x P2' <= 254, where
    P1' = round(P1 / 2^s) and P2' = round(P2 / 2^s), at least P1' + 1."""
    for shift in range(32):
        q1 = round(p1 / 2**shift)
        q2 = max(q1 + 1, round(p2 / 2**shift))
        if (census_bits >> shift) + 2 * q2 <= PATH_COST_MAX:
            return shift, q1, q2
    msg = f"no shift fits P2 {p2}"
    raise ValueError(msg)


# Predecessor offsets (dy, dx) of the 8 paths; the first 4 are the 4-path mode.
PATHS = ((0, -1), (0, 1), (-1, 0), (1, 0), (-1, 1), (-1, -1), (1, 1), (1, -1))
# The 5-path mode: the paths from the side and from the row above, aggregated per row strip; the 6-path mode
# adds a coarse path from below (``bottom_up``).
TOP_DOWN_PATHS = ((0, -1), (0, 1), (-1, 0), (-1, 1), (-1, -1))
STRIP_WARMUP = 48  # the 5-path mode's lower strip starts this many rows (at most half the image) above its first


def strips(height: int) -> tuple[tuple[int, int, int], ...]:
    """The 5-path mode's two strips, (first row aggregated, first row kept, end): as many rows each."""
    warmup = min(STRIP_WARMUP, height // 2)
    split = (height + warmup) // 2
    return ((0, 0, split), (split - warmup, split, height))


def census(image: np.ndarray, height: int = 7, width: int = 9) -> np.ndarray:
    """Bit per neighbour, set where it is darker than the centre (any fixed bit order)."""
    hh, hw = height // 2, width // 2
    padded = np.pad(image, ((hh, hh), (hw, hw)), mode="edge")
    h, w = image.shape
    bits = np.zeros((h, w), np.uint64)
    for dy in range(height):
        for dx in range(width):
            if (dy, dx) != (hh, hw):
                darker = padded[dy : dy + h, dx : dx + w] < image
                bits = (bits << np.uint64(1)) | darker.astype(np.uint64)
    return bits


def costs(left: np.ndarray, right: np.ndarray, min_d: int, nd: int, shift: int) -> np.ndarray:
    """C[y, x, k] = Hamming(census_left(x), census_right(max(x - min_d - k, 0))) >> shift."""
    cl, cr = census(left), census(right)
    h, w = left.shape
    out = np.zeros((h, w, nd), np.int64)
    for k in range(nd):
        xr = np.maximum(np.arange(w) - min_d - k, 0)
        diff = cl ^ cr[:, xr]
        ones = np.unpackbits(diff.view(np.uint8).reshape(h, w, 8), axis=2).sum(axis=2)
        out[:, :, k] = ones >> shift
    return out


def p2_table(p1: int, p2: int, gamma: float) -> np.ndarray:
    steps = np.arange(256)
    return np.array([max(p1 + 1, int(p2 / (1.0 + g / gamma))) for g in steps], np.int64)


def _step(cost: np.ndarray, prev: np.ndarray, p1: int, p2: np.ndarray) -> np.ndarray:
    """One SGM step for many pixels at once: cost, prev (n, nd), p2 (n,)."""
    big = np.iinfo(np.int64).max // 4
    pad = np.pad(prev, ((0, 0), (1, 1)), constant_values=big)
    low = prev.min(axis=1, keepdims=True)
    best = np.minimum(np.minimum(prev, np.minimum(pad[:, :-2], pad[:, 2:]) + p1), low + p2[:, None])
    out: np.ndarray = cost + best - low
    return out


def bottom_up(cost: np.ndarray, image: np.ndarray, p1: int, p2_of: np.ndarray) -> np.ndarray:
    """The 6-path mode's path from below: predecessor (y + 2, x), computed on rows h - 1, h - 3, ... and
    columns 0, 2, ...; a row between takes the computed row below it, a column between the one left of it."""
    h, w, _ = cost.shape
    grey = image.astype(np.int64)
    columns = np.arange(0, w, 2)
    path = np.zeros_like(cost)
    for y in range(h - 1, -1, -2):
        if y == h - 1:
            computed = cost[y, columns]
        else:
            p2 = p2_of[np.abs(grey[y, columns] - grey[y + 2, columns])]
            computed = _step(cost[y, columns], computed, p1, p2)
        path[y] = np.repeat(computed, 2, axis=0)[:w]
        if y >= 1:
            path[y - 1] = path[y]
    return path


def aggregate(
    cost: np.ndarray, image: np.ndarray, p1: int, p2_of: np.ndarray, paths: tuple[tuple[int, int], ...]
) -> np.ndarray:
    """S = sum over the paths (predecessor offsets) of L_r."""
    h, w, _ = cost.shape
    grey = image.astype(np.int64)
    total = np.zeros_like(cost)
    for dy, dx in paths:
        path = np.zeros_like(cost)
        if dy == 0:  # along rows: all rows at once, column by column
            for x in range(w) if dx < 0 else range(w - 1, -1, -1):
                col = x + dx
                if not 0 <= col < w:
                    path[:, x] = cost[:, x]
                    continue
                p2 = p2_of[np.abs(grey[:, x] - grey[:, col])]
                path[:, x] = _step(cost[:, x], path[:, col], p1, p2)
        else:  # from the row above / below: the whole row at once
            for y in range(h) if dy < 0 else range(h - 1, -1, -1):
                yq = y + dy
                if not 0 <= yq < h:
                    path[y] = cost[y]
                    continue
                xq = np.arange(w) + dx
                inside = (xq >= 0) & (xq < w)
                xq = np.clip(xq, 0, w - 1)
                p2 = p2_of[np.abs(grey[y] - grey[yq, xq])]
                path[y] = np.where(inside[:, None], _step(cost[y], path[yq, xq], p1, p2), cost[y])
        total += path
    return total


def match(
    left: np.ndarray,
    right: np.ndarray,
    *,
    min_disparity: int,
    num_disparities: int,
    P1: float,
    P2: float,
    uniqueness_ratio: float,
    disp12_max_diff: int,
    paths: int = 6,
    p2_gamma: float = 4.0,
    conf_gain: float = 1.5,
    lr_penalty: float = 0.5,
) -> tuple[np.ndarray, np.ndarray]:
    """(disparity with NaN holes, confidence) before median, speckle and gap filtering."""
    shift, p1, p2 = cost_shift(62, P1, P2)
    cost = costs(left, right, min_disparity, num_disparities, shift)
    p2_of = p2_table(p1, p2, p2_gamma)
    if paths in (5, 6):  # each strip's paths start at its first row; rows before ``first`` only warm them up
        total = bottom_up(cost, left, p1, p2_of) if paths == 6 else np.zeros_like(cost)
        for start, first, end in strips(left.shape[0]):
            total[first:end] += aggregate(cost[start:end], left[start:end], p1, p2_of, TOP_DOWN_PATHS)[first - start :]
    else:
        total = aggregate(cost, left, p1, p2_of, PATHS[:paths])
    h, w, nd = total.shape
    disparity = np.full((h, w), np.nan, np.float32)
    confidence = np.zeros((h, w), np.float32)
    unique = np.float32(1.0) - np.float32(uniqueness_ratio / 100.0)
    for y in range(h):
        row = total[y]
        right_k = np.full(w, -1)
        for xr in range(w):  # the right view: argmin_k S[xr + min_d + k, k], smallest k on ties
            ks = np.arange(nd)
            ks = ks[xr + min_disparity + ks < w]
            if ks.size:
                right_k[xr] = ks[np.argmin(row[xr + min_disparity + ks, ks])]
        for x in range(w):
            kmax = min(nd, x - min_disparity + 1)
            if kmax <= 0:
                continue
            s = row[x, :kmax]
            bk = int(np.argmin(s))
            if kmax < nd and bk == kmax - 1:
                continue
            far = np.abs(np.arange(kmax) - bk) > 1
            rival = np.float32(s[far].min()) if far.any() else None
            best = np.float32(s[bk])
            if rival is not None and rival * unique < best:
                continue
            diff = abs(int(right_k[x - min_disparity - bk]) - bk)
            if disp12_max_diff >= 0 and diff > disp12_max_diff:
                continue
            sub = np.float32(0.0)
            if 0 < bk < kmax - 1:
                lo, hi = np.float32(s[bk - 1]), np.float32(s[bk + 1])
                den = lo + hi - np.float32(2.0) * best
                if den > 0:
                    sub = (lo - hi) / (np.float32(2.0) * den)
            disparity[y, x] = np.float32(min_disparity + bk) + sub
            ratio = np.float32(1.0) if rival is None else (rival - best) / max(rival, np.float32(1.0))
            c = min(np.float32(1.0), ratio * np.float32(conf_gain))
            confidence[y, x] = c * np.float32(lr_penalty) if diff > 0 else c
    return disparity, confidence
