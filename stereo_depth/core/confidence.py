"""A confidence in [0, 1] for the OpenCV-compatible matchers (bm, sgbm), from their disparity alone.

census_sgm gives its own (its cost curve's margin and the left-right check). StereoBM and StereoSGBM
give a disparity only, and a second (right-to-left) match would double their time, so the confidence
is read from the disparity's neighbourhood, which costs a few image-wide filters:

  * support: the share of valid pixels in the 5x5 neighbourhood, times the square of that share in
    the 15x15 one: wrong matches gather next to the holes the matcher's own checks (uniqueness,
    left-right, speckles) leave;
  * consistency: 1 / (1 + |d - mean| / 0.5 px), the mean of the valid disparities in the 5x5
    neighbourhood (their variance ranked no better, at two more image-wide passes).

Their product ranks the pixels (at the 80 % most confident: 0.39x the bad-2 of all valid pixels for
sgbm and bm, 38 Middlebury 2001-2014 and KITTI scenes). A per-matcher piecewise-linear map then puts it
on census_sgm's scale: a threshold keeps about the same share of the valid pixels for every matcher
(0.25: 88 %, 0.5: 78 %, 0.75: 70 %). Invalid pixels get 0. The image's texture ranked the kept
pixels barely better than chance (the matchers have already dropped the flat ones), and the distance
to the nearest hole no better than the 15x15 share at four times its cost, so neither is used.
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

NEIGHBOURHOOD = (5, 5)
AREA = NEIGHBOURHOOD[0] * NEIGHBOURHOOD[1]
DEVIATION_SCALE = 0.5  # px: consistency 0.5 at this distance from the neighbourhood's mean
SURROUND = (15, 15)  # the wider neighbourhood whose share of valid pixels counts (squared)
# The product's values (per matcher) that keep census_sgm's share of the valid pixels at confidence
# 0.25, 0.5 and 0.75 (measured over Middlebury 2001-2014 and KITTI, 44 scenes, bench/accuracy.py confidence).
CONFIDENCE_LEVELS = (0.0, 0.25, 0.5, 0.75, 1.0)
SCORE_AT_LEVEL = {
    "sgbm": (0.0, 0.4096, 0.6700, 0.7722, 1.0),
    "bm": (0.0, 0.2727, 0.4571, 0.5926, 1.0),
}


def neighbourhood_confidence(disparity: np.ndarray, matcher: str) -> np.ndarray:
    """float32 confidence of each pixel of `disparity` (NaN = invalid) as `matcher` ("bm" or "sgbm")
    gave it: 0 where invalid."""
    index = cv2.convertScaleAbs(neighbourhood_score(disparity), alpha=LEVELS - 1)  # rounds to 0..255
    confidence: np.ndarray = cv2.LUT(index, _level_table(matcher))  # 0 where invalid (its score is 0)
    return confidence


def neighbourhood_score(disparity: np.ndarray) -> np.ndarray:
    """The product the confidence ranks by, in [0, 1] (float32; 0 where invalid), in cv2's own loops:
    three box filters and a few image-wide products."""
    valid = np.isfinite(disparity).view(np.uint8)
    values = disparity.copy()
    cv2.patchNaNs(values, 0.0)
    count = cv2.boxFilter(valid, cv2.CV_32F, NEIGHBOURHOOD, normalize=False, borderType=cv2.BORDER_CONSTANT)
    total = cv2.boxFilter(values, -1, NEIGHBOURHOOD, normalize=False, borderType=cv2.BORDER_CONSTANT)
    surround = cv2.boxFilter(valid, cv2.CV_32F, SURROUND, borderType=cv2.BORDER_CONSTANT)  # share valid
    # count x |d - mean|; count (1 + |d - mean| / DEVIATION_SCALE)
    deviation = cv2.absdiff(cv2.multiply(values, count), total)
    damped = np.asarray(cv2.scaleAdd(deviation, 1.0 / DEVIATION_SCALE, count), np.float32)
    damped += np.float32(1e-6)  # 0 only where no pixel around is valid
    # surround^2 x count / area / (1 + |d - mean| / DEVIATION_SCALE), 0 where invalid
    support = cv2.multiply(cv2.multiply(surround, surround), valid, dtype=cv2.CV_32F)
    support = cv2.multiply(support, cv2.multiply(count, count))
    score: np.ndarray = cv2.divide(support, damped, scale=1.0 / AREA)
    return score


LEVELS = 256  # the score is read in 1/255 steps


@functools.cache
def _level_table(matcher: str) -> np.ndarray:
    """The piecewise-linear map from score to confidence, tabulated at the score's 256 steps."""
    steps = np.arange(LEVELS, dtype=np.float64) / (LEVELS - 1)
    return np.interp(steps, SCORE_AT_LEVEL[matcher], CONFIDENCE_LEVELS).astype(np.float32).reshape(1, LEVELS)
