"""What follows every matcher, before any filter: its confidence (read from the disparity where the
matcher gives none) and the pixels too near for the disparity range, taken out of it.

With near detection on, a pixel matched at the smallest disparity searched is kept only where the
confidence backs it and the coarse search does not put it in the nearer three quarters of the range:
there a surface too near for the range, whose cost curve wrapped round, would pass for one as far as
the matcher sees and cast a points2_clearing ray through the real obstacle (on the Middlebury and
KITTI scenes beyond 64 px run at 64, `default` cast 3,072 such rays, 387 after the detection and none
with the confidence; census_sgm's own confidence was 0.9 or more on 20 of its 517, which the coarse
search put at 60-68 px; bench/accuracy.py too-near)."""

from __future__ import annotations

import numpy as np

from stereo_depth.core.confidence import neighbourhood_confidence
from stereo_depth.core.filters import fill_holes
from stereo_depth.core.matching import MatchResult
from stereo_depth.core.params import StereoParams
from stereo_depth.core.too_near import TooNearDetector, exclude_too_near, unfounded_fill

FAR_CONFIDENCE = 0.9  # a pixel at the smallest disparity searched is kept only this sure of it


class MatchChecks:
    """For one thread's matcher (its parameters at the matched size)."""

    def __init__(self, params: StereoParams) -> None:
        self._matcher = params.matcher
        self._near = TooNearDetector(params) if params.near_detection else None
        self._range = params.disparity_range
        self._smallest = np.float32(params.min_disparity + 1)  # below: matched at the smallest disparity

    def apply(self, match: MatchResult, left: np.ndarray, right: np.ndarray) -> None:
        if match.confidence is None:  # the OpenCV-compatible matchers
            match.confidence = neighbourhood_confidence(match.disparity, self._matcher)
        if self._near is None:
            return
        verdict = self._near.detect(left, right, match.disparity)
        with np.errstate(invalid="ignore"):  # NaN: not matched
            unsure_far = (match.disparity < self._smallest) & (
                (match.confidence < np.float32(FAR_CONFIDENCE)) | verdict.not_far
            )
        match.disparity[unsure_far] = np.nan
        match.confidence[unsure_far] = 0.0
        exclude_too_near(match, verdict)

    def fill(self, match: MatchResult, left: np.ndarray, radius: int) -> None:
        """fill_holes, but neither over the too-near pixels nor beside them where the coarse search
        does not back the fill."""
        holes = np.isnan(match.disparity)
        match.disparity = fill_holes(match.disparity, left, radius=radius, keep_invalid=match.excluded)
        unfounded = unfounded_fill(match, holes, self._range)
        if unfounded.any():
            match.disparity[unfounded] = np.nan
            match.excluded = unfounded if match.excluded is None else match.excluded | unfounded
