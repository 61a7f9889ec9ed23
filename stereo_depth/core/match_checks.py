"""What follows every matcher, before any filter: its confidence (read from the disparity where the
matcher gives none) and the pixels too near for the disparity range, taken out of it."""

from __future__ import annotations

import numpy as np

from stereo_depth.core.confidence import neighbourhood_confidence
from stereo_depth.core.matching import MatchResult
from stereo_depth.core.params import StereoParams
from stereo_depth.core.too_near import TooNearDetector, exclude_too_near


class MatchChecks:
    """For one thread's matcher (its parameters at the matched size)."""

    def __init__(self, params: StereoParams) -> None:
        self._matcher = params.matcher
        self._near = TooNearDetector(params) if params.near_detection else None

    def apply(self, match: MatchResult, left: np.ndarray, right: np.ndarray) -> None:
        if match.confidence is None:  # the OpenCV-compatible matchers
            match.confidence = neighbourhood_confidence(match.disparity, self._matcher)
        if self._near is not None:
            exclude_too_near(match, self._near.detect(left, right, match.disparity))
