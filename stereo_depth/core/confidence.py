"""A confidence in [0, 1] for the OpenCV-compatible matchers (bm, sgbm), from their disparity alone.

census_sgm gives its own (its cost curve's margin and the left-right check). StereoBM and StereoSGBM
give a disparity only, and a second (right-to-left) match would double their time, so the confidence
is read from the disparity's neighbourhood, which costs a few image-wide filters:

  * support: the share of valid pixels in the 5x5 neighbourhood, times the square of that share in
    the 15x15 one: wrong matches gather next to the holes the matcher's own checks (uniqueness,
    left-right, speckles) leave;
  * consistency: 1 / (1 + variance / 0.5 px^2) of the valid disparities in the 5x5 neighbourhood.

Their product ranks the pixels (at the 80 % most confident: 0.40x the bad-2 of all valid pixels for
sgbm, 0.39x for bm, Middlebury 2001-2014 and KITTI). A per-matcher piecewise-linear map then puts it
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
VARIANCE_SCALE = 0.5  # px^2: consistency 0.5 at this local disparity variance
SURROUND = (15, 15)  # the wider neighbourhood whose share of valid pixels counts (squared)
# The product's values (per matcher) that keep census_sgm's share of the valid pixels at confidence
# 0.25, 0.5 and 0.75 (measured over Middlebury 2001-2014 and KITTI, 44 scenes, bench/accuracy.py confidence).
CONFIDENCE_LEVELS = (0.0, 0.25, 0.5, 0.75, 1.0)
SCORE_AT_LEVEL = {
    "sgbm": (0.0, 0.3400, 0.6509, 0.7942, 1.0),
    "bm": (0.0, 0.2857, 0.4803, 0.6231, 1.0),
}


def neighbourhood_confidence(disparity: np.ndarray, matcher: str) -> np.ndarray:
    """float32 confidence of each pixel of `disparity` (NaN = invalid) as `matcher` ("bm" or "sgbm")
    gave it: 0 where invalid."""
    index = cv2.convertScaleAbs(neighbourhood_score(disparity), alpha=LEVELS - 1)  # rounds to 0..255
    confidence: np.ndarray = cv2.LUT(index, _level_table(matcher))  # 0 where invalid (its score is 0)
    return confidence


def neighbourhood_score(disparity: np.ndarray) -> np.ndarray:
    """The product the confidence ranks by, in [0, 1] (float32; 0 where invalid): cv2's own loops, a few
    image-wide passes."""
    valid = np.isfinite(disparity).view(np.uint8)
    values = disparity.copy()
    cv2.patchNaNs(values, 0.0)
    count = cv2.boxFilter(valid, cv2.CV_32F, NEIGHBOURHOOD, normalize=False, borderType=cv2.BORDER_CONSTANT)
    total = cv2.boxFilter(values, -1, NEIGHBOURHOOD, normalize=False, borderType=cv2.BORDER_CONSTANT)
    squares = cv2.boxFilter(
        cv2.multiply(values, values), -1, NEIGHBOURHOOD, normalize=False, borderType=cv2.BORDER_CONSTANT
    )
    surround = cv2.boxFilter(valid, cv2.CV_32F, SURROUND, borderType=cv2.BORDER_CONSTANT)  # share valid
    # count^2 x variance; count^2 (1 + variance / VARIANCE_SCALE)
    spread = np.maximum(cv2.subtract(cv2.multiply(squares, count), cv2.multiply(total, total)), np.float32(0.0))
    count_squared = cv2.multiply(count, count)
    damped = np.asarray(cv2.scaleAdd(spread, 1.0 / VARIANCE_SCALE, count_squared), np.float32)
    damped += np.float32(1e-6)  # 0 only where no pixel around is valid
    # surround^2 x count / area x 1 / (1 + variance / VARIANCE_SCALE)
    weight = cv2.multiply(cv2.multiply(surround, surround), valid, dtype=cv2.CV_32F)
    support = cv2.multiply(cv2.multiply(weight, count), count_squared)
    score: np.ndarray = cv2.divide(support, damped, scale=1.0 / AREA)
    return score


LEVELS = 256  # the score is read in 1/255 steps


@functools.cache
def _level_table(matcher: str) -> np.ndarray:
    """The piecewise-linear map from score to confidence, tabulated at the score's 256 steps."""
    steps = np.arange(LEVELS, dtype=np.float64) / (LEVELS - 1)
    return np.interp(steps, SCORE_AT_LEVEL[matcher], CONFIDENCE_LEVELS).astype(np.float32).reshape(1, LEVELS)
