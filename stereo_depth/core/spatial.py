"""Spatial filter: edge-preserving smoothing of the disparity within each surface.

The recursive form of the domain transform (Gastal and Oliveira, "Domain Transform for Edge-Aware Image
and Video Processing", SIGGRAPH 2011), guided by the disparity itself, with the step weight RealSense's
spatial filter uses: along each row, left to right and back, then along each column, down and back up,
a pixel's value becomes `alpha` of its own plus `1 - alpha` of its smoothed neighbour's, where the two
lie within `delta` px of each other (one surface); a larger step is a depth edge, and the smoothing
starts anew behind it. Invalid pixels (NaN) are skipped and break the chain: nothing is filled, nothing
invalid spreads, the set of valid pixels never changes. `iterations` repeats the four passes (a wider
reach). Deterministic (no fastmath), so live and offline give the same bytes. numba-compiled on first
use, then cached.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class SpatialSettings:
    """The filter's parameters (the `spatial_*` processing options)."""

    alpha: float = 0.5  # a pixel's own weight: 1 leaves the disparity as it is
    delta: float = 2.0  # px: a larger step between neighbours is a depth edge
    iterations: int = 2


def spatial_filter(disparity: np.ndarray, settings: SpatialSettings) -> np.ndarray:
    """The smoothed disparity (float32, NaN invalid, as given), a new array.

    Each iteration runs the row passes as column passes of the transposed image: a column pass blends a
    whole row with the one before it, an inner loop along memory without a dependency from pixel to pixel,
    which runs as vectors (the row passes proper would chain every pixel to the one before it)."""
    smooth = _kernels()["columns"]
    alpha, delta = np.float32(settings.alpha), np.float32(settings.delta)
    out = np.ascontiguousarray(disparity, np.float32)
    for _ in range(settings.iterations):
        transposed = np.ascontiguousarray(out.T)  # a copy: the input stays as it is
        smooth(transposed, alpha, delta)
        out = np.ascontiguousarray(transposed.T)
        smooth(out, alpha, delta)
    return out


def compile_kernels() -> None:
    """Compile the kernel (or load it from numba's cache) now, so that no frame waits for it."""
    spatial_filter(np.ones((2, 2), np.float32), SpatialSettings())


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

    return {"columns": numba.njit(cache=True, nogil=True)(_smooth_columns)}
