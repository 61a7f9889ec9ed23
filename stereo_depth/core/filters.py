"""Post-filters on float32 disparity (NaN = invalid), usable after any matching core."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from stereo_depth.core.matching import MatchResult


def apply_confidence_threshold(match: MatchResult, threshold: float) -> None:
    """Trade density for correctness: drop matches the core itself is unsure of."""
    assert match.confidence is not None
    unsure = match.confidence < threshold
    match.disparity[unsure] = np.nan
    match.confidence[unsure] = 0.0


def fill_holes(
    disparity: np.ndarray, left: np.ndarray, radius: int, keep_invalid: np.ndarray | None = None
) -> np.ndarray:
    """Dense disparity: background-favouring fill of every hole, smoothed along image edges; the pixels
    of `keep_invalid` (a detector's verdict that nothing there can be trusted) stay invalid."""
    from stereo_depth.core.census_sgm import fill_holes as edge_aware_fill

    filled = edge_aware_fill(disparity, left, radius=radius)
    if keep_invalid is not None:
        filled[keep_invalid] = np.nan
    return filled
