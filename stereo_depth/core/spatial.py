"""Spatial filter: wrong matches replaced by their surface's value, then edge-preserving smoothing of the
disparity within each surface.

First an outlier pass, run twice: a valid pixel on a step (one of its 8 neighbours more than `delta`
away: a depth edge or the rim of a wrong match; elsewhere the smoothing does the work) takes the median of
the valid disparities of its (2 * `outlier_radius` + 1)^2 window, each weighted by how close its grey value
is to the pixel's own, where at least half the window is valid and that median lies more than 1 px from
it. An isolated wrong match, or a small patch of them, lies on a surface the window mostly sees and takes
its value; a structure the image shows keeps its own, and the grey weights keep a depth edge where the
image has one. The second run looks only at the windows the first changed. Then the recursive form of the domain
transform (Gastal and Oliveira, "Domain Transform for Edge-Aware Image and Video Processing", SIGGRAPH
2011), guided by the disparity itself, with the step weight RealSense's spatial filter uses: along each
row, left to right and back, then along each column, down and back up, a pixel's value becomes `alpha` of
its own plus `1 - alpha` of its smoothed neighbour's, where the two lie within `delta` px of each other
(one surface); a larger step is a depth edge, and the smoothing starts anew behind it. `iterations` repeats
the four passes (a wider reach). Invalid pixels (NaN) are skipped by both: nothing is filled, nothing
invalid spreads, the set of valid pixels never changes. Deterministic (no fastmath), so live and offline
give the same bytes. numba-compiled on first use, then cached.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

OUTLIER_PASSES = 2
OUTLIER_STEP = np.float32(1.0)  # px: a pixel this far from its guided median is a wrong match
GREY_SIGMA = 10.0  # grey levels: a neighbour this much darker or brighter weighs 1/e


@dataclass(frozen=True)
class SpatialSettings:
    """The filter's parameters (the `spatial_*` processing options)."""

    alpha: float = 0.5  # a pixel's own weight: 1 leaves the disparity as it is
    delta: float = 2.0  # px: a larger step between neighbours is a depth edge
    iterations: int = 2
    outlier_radius: int = 3  # px: the outlier pass's window reaches this far (0: no outlier pass)


def spatial_filter(disparity: np.ndarray, settings: SpatialSettings, grey: np.ndarray) -> np.ndarray:
    """The filtered disparity (float32, NaN invalid, as given), a new array; `grey` is the rectified left
    image (uint8) of the same size, which guides the outlier pass.

    Each iteration runs the row passes as column passes of the transposed image: a column pass blends a
    whole row with the one before it, an inner loop along memory without a dependency from pixel to pixel,
    which runs as vectors (the row passes proper would chain every pixel to the one before it)."""
    kernels = _kernels()
    alpha, delta = np.float32(settings.alpha), np.float32(settings.delta)
    out = np.ascontiguousarray(disparity, np.float32)
    if settings.outlier_radius > 0:
        weights = np.exp(-np.arange(256, dtype=np.float32) / np.float32(GREY_SIGMA)).astype(np.float32)
        guide = np.ascontiguousarray(grey, np.uint8)
        radius = settings.outlier_radius
        looked_at = kernels["steps"](out, delta)
        for _ in range(OUTLIER_PASSES):
            out, looked_at = kernels["outliers"](out, looked_at, guide, radius, weights, delta)
    for _ in range(settings.iterations):
        transposed = np.ascontiguousarray(out.T)  # a copy: the input stays as it is
        kernels["columns"](transposed, alpha, delta)
        out = np.ascontiguousarray(transposed.T)
        kernels["columns"](out, alpha, delta)
    return out


def compile_kernels() -> None:
    """Compile the kernels (or load them from numba's cache) now, so that no frame waits for them."""
    spatial_filter(np.ones((2, 2), np.float32), SpatialSettings(), np.zeros((2, 2), np.uint8))


def _on_a_step(disparity: np.ndarray, delta: np.float32) -> np.ndarray:
    """The valid pixels (uint8, 1) with one of their 8 neighbours more than `delta` away: a depth edge or the
    rim of a wrong match. Whole rows at a time, which run as vectors (NaN compares false: never a step)."""
    height, width = disparity.shape
    steps = np.zeros((height, width), np.uint8)
    for y in range(height):
        row, marks = disparity[y], steps[y]
        for other_y in range(max(y - 1, 0), min(y + 2, height)):
            other = disparity[other_y]
            for shift in range(-1, 2):
                for x in range(max(-shift, 0), min(width - shift, width)):
                    marks[x] |= np.uint8(abs(row[x] - other[x + shift]) > delta)
    return steps


def _replace_outliers(
    disparity: np.ndarray, looked_at: np.ndarray, grey: np.ndarray, radius: int, weights: np.ndarray, delta: np.float32
) -> tuple[np.ndarray, np.ndarray]:
    """A new array, and the pixels whose window holds a replaced one (uint8), which the next pass looks at:
    no other pixel's window has changed.

    A pixel of `looked_at` (uint8) on a step (as in _on_a_step) takes the grey-weighted median of the
    window's valid values, if at least half the window is valid and the median lies more than OUTLIER_STEP
    from it. The weight of the values below and above the pixel's own tells first, without a sort, whether
    the median lies that far."""
    height, width = disparity.shape
    out = disparity.copy()
    touched = np.zeros((height, width), np.uint8)
    size = (2 * radius + 1) ** 2
    enough = (size + 1) // 2
    for y in range(height):
        values = np.empty(size, np.float32)
        value_weights = np.empty(size, np.float32)
        for x in range(width):
            if not looked_at[y, x]:
                continue
            value = disparity[y, x]
            step = False  # NaN compares false: a hole is never on a step, and stays a hole
            for yy in range(max(y - 1, 0), min(y + 2, height)):
                for xx in range(max(x - 1, 0), min(x + 2, width)):
                    step |= abs(disparity[yy, xx] - value) > delta
            if not step:
                continue
            centre = np.int32(grey[y, x])
            low, high = value - OUTLIER_STEP, value + OUTLIER_STEP
            top, bottom = max(y - radius, 0), min(y + radius + 1, height)
            left, right = max(x - radius, 0), min(x + radius + 1, width)
            count, total, below, above = 0, np.float32(0.0), np.float32(0.0), np.float32(0.0)
            for yy in range(top, bottom):
                for xx in range(left, right):
                    # without branches, which would mispredict at every edge: an invalid neighbour weighs 0
                    neighbour = disparity[yy, xx]
                    valid = neighbour == neighbour
                    weight = weights[abs(np.int32(grey[yy, xx]) - centre)] * np.float32(valid)
                    count += int(valid)
                    total += weight
                    below += weight * np.float32(neighbour < low)
                    above += weight * np.float32(neighbour > high)
            half = total * np.float32(0.5)
            if count < enough or (below <= half and above <= half):
                continue
            # the median lies among the values more than OUTLIER_STEP below (or above): sort those alone,
            # from the weight of all the values before them
            from_below = below > half
            running = np.float32(0.0) if from_below else total - above
            count = 0
            for yy in range(top, bottom):
                for xx in range(left, right):
                    neighbour = disparity[yy, xx]
                    if (neighbour < low) if from_below else (neighbour > high):
                        values[count] = neighbour
                        value_weights[count] = weights[abs(np.int32(grey[yy, xx]) - centre)]
                        count += 1
            for i in range(1, count):  # insertion sort by value, in place: no allocation per pixel
                held, held_weight, j = values[i], value_weights[i], i - 1
                while j >= 0 and values[j] > held:
                    values[j + 1], value_weights[j + 1] = values[j], value_weights[j]
                    j -= 1
                values[j + 1], value_weights[j + 1] = held, held_weight
            for i in range(count):
                running += value_weights[i]
                if running >= half:
                    out[y, x] = values[i]
                    touched[top:bottom, left:right] = 1
                    break
    return out, touched


def _smooth_columns(disparity: np.ndarray, alpha: np.float32, delta: np.float32) -> None:
    """In place: down the columns, then back up, each pixel blended with its already smoothed neighbour
    where both are valid and within `delta` (NaN compares false: an invalid pixel neither moves nor moves
    another)."""
    height, width = disparity.shape
    keep = np.float32(1.0) - alpha
    for y in range(1, height):
        row, above = disparity[y], disparity[y - 1]
        for x in range(width):
            value, neighbour = row[x], above[x]
            row[x] = alpha * value + keep * neighbour if abs(value - neighbour) <= delta else value
    for y in range(height - 2, -1, -1):
        row, below = disparity[y], disparity[y + 1]
        for x in range(width):
            value, neighbour = row[x], below[x]
            row[x] = alpha * value + keep * neighbour if abs(value - neighbour) <= delta else value


@functools.cache
def _kernels() -> dict[str, Callable[..., Any]]:
    """numba-compiled kernels, built (or loaded from numba's cache) on first use."""
    import numba

    return {
        "steps": numba.njit(cache=True, nogil=True)(_on_a_step),
        "outliers": numba.njit(cache=True, nogil=True)(_replace_outliers),
        "columns": numba.njit(cache=True, nogil=True)(_smooth_columns),
    }
