"""Post-filters on float32 disparity (NaN = invalid), usable after any matching core."""

from __future__ import annotations

import numpy as np


def fill_holes_scanline(disparity: np.ndarray) -> np.ndarray:
    """Fill each invalid run with the smaller of its nearest valid neighbours on the row.

    Holes are mostly occlusions next to a depth edge, where the background (the smaller disparity) is
    the right guess. Rows with no valid pixel stay invalid.
    """
    h, w = disparity.shape
    valid = np.isfinite(disparity)
    cols = np.arange(w)
    left_idx = np.where(valid, cols, -1)
    np.maximum.accumulate(left_idx, axis=1, out=left_idx)
    right_idx = np.where(valid, cols, w)
    right_idx = np.minimum.accumulate(right_idx[:, ::-1], axis=1)[:, ::-1]
    rows = np.arange(h)[:, None]
    padded = np.concatenate([disparity, np.full((h, 1), np.inf, np.float32)], axis=1)
    left_val = np.where(left_idx >= 0, padded[rows, np.clip(left_idx, 0, w)], np.inf)
    right_val = np.where(right_idx < w, padded[rows, np.clip(right_idx, 0, w)], np.inf)
    filled = np.where(valid, disparity, np.minimum(left_val, right_val)).astype(np.float32)
    filled[~np.isfinite(filled)] = np.nan
    return filled
