"""Pixels too near for the disparity range: their true disparity lies beyond the largest one searched.

A matcher cannot give such a pixel its disparity, and often gives it a smaller one anyway: the surface
comes out farther away than it is (on Middlebury scenes run at 64 disparities, about half of those
pixels came out valid with SGBM, every one wrong by more than 2 px), and one matched at the smallest
disparity even casts a clearing ray through the real obstacle. Two cues find them, both from what the
matchers see:

  * a coarse search beyond the range: SGBM at 1/4 resolution over twice the range (1/32 of the full
    search's disparity-pixels), its images padded on the left so that the left border is searched too:
    a pixel it puts at or beyond the range's top is too near;
  * the cost still falling at the top of the range: a pixel matched at the largest disparity searched.

Measured over the 10 Middlebury and KITTI scenes whose ground truth exceeds 64 px, run at 64
(bench/accuracy.py too-near): of the pixels more than 2 px beyond the range, 0.45 came out valid with
`default` and 0.04 with detection; 0.01 of the pixels more than 2 px within it were lost.
"""

from __future__ import annotations

import cv2
import numpy as np

from stereo_depth.core.matching import MatchResult
from stereo_depth.core.params import StereoParams

COARSE_LEVELS = 16  # the coarse search sees the range in at least this many steps: its images are
COARSE_FACTORS = (4, 2)  # 1/4 the matched ones' size, or 1/2 where that would see too few
COARSE_SPAN = 2  # it searches this many times the range
COARSE_WINDOW = 3
COARSE_P1, COARSE_P2 = 8, 32  # per pixel of the window: OpenCV's suggested penalties for grey images


class TooNearDetector:
    """Finds the too-near pixels of one matcher's results (its parameters at the matched size); keeps its
    coarse SGBM object between frames, so one detector per thread."""

    def __init__(self, params: StereoParams) -> None:
        self._top = params.min_disparity + params.disparity_range - 1  # the largest disparity searched
        factors = [f for f in COARSE_FACTORS if params.disparity_range // f >= COARSE_LEVELS]
        self._factor = factors[0] if factors else COARSE_FACTORS[-1]
        self._min_disparity = params.min_disparity // self._factor
        span = -(-COARSE_SPAN * params.disparity_range // self._factor)
        self._disparities = -(-span // 16) * 16
        area = COARSE_WINDOW * COARSE_WINDOW
        self._coarse = cv2.StereoSGBM.create(
            minDisparity=self._min_disparity,
            numDisparities=self._disparities,
            blockSize=COARSE_WINDOW,
            P1=COARSE_P1 * area,
            P2=COARSE_P2 * area,
            disp12MaxDiff=-1,
            uniquenessRatio=0,
            mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY,
        )

    def detect(self, left: np.ndarray, right: np.ndarray, disparity: np.ndarray) -> np.ndarray:
        """bool mask of the pixels too near, for a pair of matched images and the disparity matched."""
        height, width = left.shape
        with np.errstate(invalid="ignore"):  # NaN: not matched
            near: np.ndarray = disparity >= np.float32(self._top)
        small = (width // self._factor, height // self._factor)
        if small[1] <= COARSE_WINDOW:  # too few rows to search at the coarse size
            return near
        pad = self._disparities + max(self._min_disparity, 0)  # the search's blind left border
        coarse_left, coarse_right = (
            cv2.copyMakeBorder(
                cv2.resize(image, small, interpolation=cv2.INTER_AREA), 0, 0, pad, 0, cv2.BORDER_REPLICATE
            )
            for image in (left, right)
        )
        coarse = self._coarse.compute(coarse_left, coarse_right)[:, pad:]
        # at or beyond the top, in 1/16 px of the coarse images
        beyond = (coarse.astype(np.int32) * self._factor >= self._top * 16).view(np.uint8)
        near |= cv2.resize(beyond, (width, height), interpolation=cv2.INTER_NEAREST) > 0
        return near


def exclude_too_near(match: MatchResult, near: np.ndarray) -> None:
    """Invalidate the too-near pixels, with a confidence of 0, and keep hole filling off them."""
    match.disparity[near] = np.nan
    if match.confidence is not None:
        match.confidence[near] = 0.0
    match.excluded = near if match.excluded is None else match.excluded | near
    match.too_near = near
