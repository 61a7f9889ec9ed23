"""Pixels too near for the disparity range: their true disparity lies beyond the largest one searched.

A matcher cannot give such a pixel its disparity, and often gives it a smaller one anyway: the surface
comes out farther away than it is (on Middlebury scenes run at 64 disparities, about half of those
pixels came out valid with SGBM, every one wrong by more than 2 px), and one matched at the smallest
disparity even casts a clearing ray through the real obstacle. Two cues find them, both from what the
matchers see:

  * a coarse search beyond the range: SGBM at 1/4 resolution over twice the range (1/32 of the full
    search's disparity-pixels), its images padded on the left so that the left border is searched too,
    with a left-right check loose by a quarter of that search (at 1 px it failed on a fifth to a half
    of the too-near pixels that `fast` refilled): a pixel it puts at or beyond the range's top is too
    near;
  * the cost still falling at the top of the range: a pixel matched at the largest disparity searched.

The coarse verdict is blocky to one of its pixels, so hole filling would carry the background over the
edge of a too-near surface: beside too-near pixels a fill stays only where the coarse search backs it.

Measured over the 10 Middlebury and KITTI scenes whose ground truth exceeds 64 px, run at 64
(bench/accuracy.py too-near): of the pixels more than 2 px beyond the range, 0.45 came out valid with
`default` and 0.03 with detection; 0.02 of the pixels more than 2 px within it were lost. `fast` fills
every hole: 0.05 of those beyond it stay valid with detection, and 0.06 of those within are lost, most
of them (76 %) fills wrong by more than 2 px.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from stereo_depth.core.matching import MatchResult
from stereo_depth.core.params import StereoParams

COARSE_LEVELS = 16  # the coarse search sees the range in at least this many steps: its images are
COARSE_FACTORS = (4, 2)  # 1/4 the matched ones' size, or 1/2 where that would see too few
COARSE_SPAN = 2  # it searches this many times the range
COARSE_WINDOW = 3
COARSE_LR_SHARE = 4  # its left-right check allows this share of its search (OpenCV's -1 means 1 px)
NEARER_SHARE = 4  # a coarse disparity this fraction of the range above the smallest is no far surface
FILL_TOLERANCE = 1 / 8  # a fill beside too-near pixels this share of the range from the coarse search stays
COARSE_P1, COARSE_P2 = 8, 32  # per pixel of the window: OpenCV's suggested penalties for grey images


class TooNearDetector:
    """Finds the too-near pixels of one matcher's results (its parameters at the matched size); keeps its
    coarse SGBM object between frames, so one detector per thread."""

    def __init__(self, params: StereoParams) -> None:
        self._top = params.min_disparity + params.disparity_range - 1  # the largest disparity searched
        self._nearer = params.min_disparity + params.disparity_range // NEARER_SHARE
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
            disp12MaxDiff=max(1, self._disparities // COARSE_LR_SHARE),
            uniquenessRatio=0,
            mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY,
        )

    def detect(self, left: np.ndarray, right: np.ndarray, disparity: np.ndarray) -> NearVerdict:
        """What the two cues say of a pair of matched images and the disparity matched."""
        height, width = left.shape
        with np.errstate(invalid="ignore"):  # NaN: not matched
            near: np.ndarray = disparity >= np.float32(self._top)
        small = (width // self._factor, height // self._factor)
        if small[1] <= COARSE_WINDOW:  # too few rows to search at the coarse size
            return NearVerdict(near, np.zeros_like(near), None)
        pad = self._disparities + max(self._min_disparity, 0)  # the search's blind left border
        coarse_left, coarse_right = (
            cv2.copyMakeBorder(
                cv2.resize(image, small, interpolation=cv2.INTER_AREA), 0, 0, pad, 0, cv2.BORDER_REPLICATE
            )
            for image in (left, right)
        )
        coarse = CoarseSearch(self._coarse.compute(coarse_left, coarse_right)[:, pad:], self._factor)
        # bit 1 at or beyond the top, bit 2 nearer than the far quarter
        scaled = coarse.raw.astype(np.int32) * self._factor  # 1/16 px of the matched images
        bits = (scaled >= self._top * 16).view(np.uint8) | ((scaled >= self._nearer * 16).view(np.uint8) << 1)
        verdict: np.ndarray = cv2.resize(bits, (width, height), interpolation=cv2.INTER_NEAREST)
        near |= (verdict & 1) > 0
        return NearVerdict(near, verdict >= 2, coarse)


@dataclass
class CoarseSearch:
    """The coarse search's disparity at its own size, as OpenCV gives it (1/16 px of its images, below
    0 none), and how many matched pixels one of its pixels spans."""

    raw: np.ndarray
    factor: int

    def at(self, shape: tuple[int, ...]) -> np.ndarray:
        """float32 disparity in px of the matched images (of `shape`), NaN where the search gave none."""
        values = self.raw.astype(np.float32) * np.float32(self.factor / 16)
        values[self.raw < 0] = np.nan
        return cv2.resize(values, (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST)


@dataclass
class NearVerdict:
    near: np.ndarray  # bool: too near for the range
    not_far: np.ndarray  # bool: the coarse search puts it in the range's nearer three quarters or beyond
    coarse: CoarseSearch | None  # None: the images were too small to search


def exclude_too_near(match: MatchResult, verdict: NearVerdict) -> None:
    """Invalidate the too-near pixels, with a confidence of 0, and keep hole filling off them."""
    near = verdict.near
    match.disparity[near] = np.nan
    if match.confidence is not None:
        match.confidence[near] = 0.0
    match.excluded = near if match.excluded is None else match.excluded | near
    match.too_near = near
    match.coarse = verdict.coarse


def unfounded_fill(match: MatchResult, holes: np.ndarray, disparity_range: int) -> np.ndarray:
    """bool mask of the filled `holes` the coarse search does not back beside too-near pixels: within
    one coarse pixel and one more of them (the verdict is blocky to a coarse pixel), a fill that differs
    from the coarse disparity by more than FILL_TOLERANCE of the range, or where it gave none, is the
    edge of the too-near surface filled from the background beyond it."""
    if match.too_near is None or match.coarse is None:
        return np.zeros_like(holes)
    reach = 2 * (match.coarse.factor + 1) + 1
    beside = cv2.dilate(match.too_near.view(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (reach, reach)))
    coarse = match.coarse.at(holes.shape)
    with np.errstate(invalid="ignore"):  # NaN: the search gave none
        backed = np.abs(match.disparity - coarse) <= np.float32(FILL_TOLERANCE * disparity_range)
    unfounded: np.ndarray = holes & (beside > 0) & ~backed
    return unfounded
