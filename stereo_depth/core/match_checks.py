"""What follows every matcher, before any filter: its confidence (read from the disparity where the
matcher gives none) and the pixels too near for the disparity range, taken out of it.

With near detection on, a pixel matched at the smallest disparity searched is kept only where the
confidence backs it: there a surface too near for the range, whose cost curve wrapped round, would
pass for one as far as the matcher sees and cast a points2_clearing ray through the real obstacle
(on the Middlebury and KITTI scenes beyond 64 px run at 64, `default` cast 3,072 such rays; 387 after
the detection, none with this rule; bench/accuracy.py too-near)."""

from __future__ import annotations

import numpy as np

from stereo_depth.core.confidence import neighbourhood_confidence
from stereo_depth.core.matching import MatchResult
from stereo_depth.core.params import StereoParams
from stereo_depth.core.too_near import TooNearDetector, exclude_too_near

FAR_CONFIDENCE = 0.9  # a pixel at the smallest disparity searched is kept only this sure of it


class MatchChecks:
    """For one thread's matcher (its parameters at the matched size)."""

    def __init__(self, params: StereoParams) -> None:
        self._matcher = params.matcher
        self._near = TooNearDetector(params) if params.near_detection else None
        self._smallest = np.float32(params.min_disparity + 1)  # below: matched at the smallest disparity

    def apply(self, match: MatchResult, left: np.ndarray, right: np.ndarray) -> None:
        if match.confidence is None:  # the OpenCV-compatible matchers
            match.confidence = neighbourhood_confidence(match.disparity, self._matcher)
        if self._near is None:
            return
        with np.errstate(invalid="ignore"):  # NaN: not matched
            unsure_far = (match.disparity < self._smallest) & (match.confidence < np.float32(FAR_CONFIDENCE))
        match.disparity[unsure_far] = np.nan
        match.confidence[unsure_far] = 0.0
        exclude_too_near(match, self._near.detect(left, right, match.disparity))
