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


def fill_holes(disparity: np.ndarray, left: np.ndarray, radius: int) -> np.ndarray:
    """Dense disparity: background-favouring fill of every hole, smoothed along image edges."""
    from stereo_depth.core.census_sgm import fill_holes as edge_aware_fill

    return edge_aware_fill(disparity, left, radius=radius)
