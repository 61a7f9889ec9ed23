"""OpenCV's speckle filter run on the two halves of an image at once, with the whole image's result.

`cv2.filterSpeckles` turns every connected region of valid pixels (4-neighbours whose disparities differ
by at most `max_diff`) of at most `size` pixels into `invalid`. Whether a pixel goes depends only on its
region, so the halves can be filtered apart, each on its own thread right after its half is matched.
Only a region that the cut between the halves splits can come out wrong: each part may look small
where the whole is not. Such a part touches the cut and, being small, lies within `size` rows of it.

So `join` re-examines the pixels that a half's filter removed on the two rows beside the cut, each
with a flood fill over the values as they were before filtering, in the band of `size` + 1 rows either
side of the cut. A fill larger than `size` belongs to a region larger than `size` (the band only
shrinks regions, and a region that reaches past the band holds a path of more than `size` pixels inside
it), so its pixels are put back; a fill of at most `size` pixels that ends inside the band is the
whole region, a speckle indeed. Pixels farther from the cut are decided by their half's filter alone:
a region the cut splits and that reaches them is larger than `size` in that half already.
"""

from __future__ import annotations

import cv2
import numpy as np

FILLING, SEEN = 2, 3  # mask values: the current fill, earlier fills (1: invalid before filtering)


class SplitSpeckleFilter:
    """`cv2.filterSpeckles(raw, invalid, size, max_diff)` as rows [0, middle) and [middle, height) of
    `raw` (int16, OpenCV's fixed-point disparity) are filled in, possibly on two threads at once:
    `filter_rows` for each half once it is written, then `join` on one thread. With `middle` equal to
    the height, one `filter_rows` over every row is the plain filter."""

    def __init__(self, raw: np.ndarray, middle: int, invalid: int, size: int, max_diff: int) -> None:
        self._raw, self._middle = raw, middle
        self._invalid, self._size, self._max_diff = invalid, size, max_diff
        height = raw.shape[0]
        cut = size > 0 and 0 < middle < height  # else nothing to join: no band kept
        band: tuple[int, int] = (max(0, middle - size - 1), min(height, middle + size + 1)) if cut else (0, 0)
        self._top, self._bottom = band
        self._before = np.empty((self._bottom - self._top, raw.shape[1]), raw.dtype)  # the band, unfiltered

    def filter_rows(self, start: int, stop: int) -> None:
        """Filter rows [start, stop) (one half) of `raw` in place, keeping what the band needs first."""
        top, bottom = max(start, self._top), min(stop, self._bottom)
        if top < bottom:
            self._before[top - self._top : bottom - self._top] = self._raw[top:bottom]
        if self._size > 0:
            cv2.filterSpeckles(self._raw[start:stop], self._invalid, self._size, self._max_diff)

    def join(self) -> tuple[int, int] | None:
        """Put back the pixels of regions that only the cut made small, once both halves are filtered;
        the rows [first, last) that changed, or None when none did."""
        middle, top, before = self._middle, self._top, self._before
        if before.shape[0] == 0:
            return None
        seam = self._raw[middle - 1 : middle + 1]
        seeds = np.argwhere((seam == self._invalid) & (before[middle - 1 - top : middle + 1 - top] != self._invalid))
        if seeds.size == 0:
            return None
        values = before.astype(np.float32)  # floodFill's types; int16 values are exact in float32
        mask = np.zeros((values.shape[0] + 2, values.shape[1] + 2), np.uint8)
        mask[1:-1, 1:-1][before == self._invalid] = 1  # invalid pixels belong to no region
        flags = 4 | cv2.FLOODFILL_MASK_ONLY | (FILLING << 8)  # 4-neighbours, each step within max_diff
        changed: tuple[int, int] | None = None
        for row, column in seeds:
            y, x = int(row) + middle - 1 - top, int(column)
            if mask[y + 1, x + 1]:
                continue  # invalid after all, or in a region filled from an earlier seed
            area, _, _, (rx, ry, rw, rh) = cv2.floodFill(values, mask, (x, y), 0, self._max_diff, self._max_diff, flags)
            window = mask[ry + 1 : ry + rh + 1, rx + 1 : rx + rw + 1]
            filled = window == FILLING
            window[filled] = SEEN
            if area > self._size:
                self._raw[top + ry : top + ry + rh, rx : rx + rw][filled] = before[ry : ry + rh, rx : rx + rw][filled]
                first, last = top + ry, top + ry + rh
                changed = (first, last) if changed is None else (min(changed[0], first), max(changed[1], last))
        return changed
