"""Matching cores behind one interface, chosen by name.

A core turns a rectified grey pair into float32 disparity (left reference, d = x_left - x_right,
NaN = invalid) and optionally a confidence in [0, 1]. The OpenCV cores keep their matcher object
between frames; a parameter change builds a new core, never mutates one in use.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np

from stereo_depth.core.params import StereoParams


@dataclass
class MatchResult:
    disparity: np.ndarray
    confidence: np.ndarray | None = None


class Matcher(Protocol):
    def compute(self, left: np.ndarray, right: np.ndarray) -> MatchResult:
        """left/right: rectified uint8 grey images of equal size."""
        ...


def fixed_point_to_float(raw: np.ndarray, min_disparity: int) -> np.ndarray:
    """OpenCV's int16 disparity (x16) to float32 pixels; below min_disparity means invalid."""
    disparity = raw.astype(np.float32)
    disparity *= 1.0 / 16.0
    disparity[raw < min_disparity * 16] = np.nan
    return disparity


class OpenCVMatcher:
    """Wraps cv2.StereoBM / cv2.StereoSGBM (their speckle filter and LR check run inside OpenCV)."""

    def __init__(self, stereo: cv2.StereoMatcher, min_disparity: int) -> None:
        self._stereo = stereo
        self._min_disparity = min_disparity

    def compute(self, left: np.ndarray, right: np.ndarray) -> MatchResult:
        raw = self._stereo.compute(left, right)
        return MatchResult(fixed_point_to_float(raw, self._min_disparity))


def create_bm(params: StereoParams) -> Matcher:
    bm = cv2.StereoBM.create(params.disparity_range, params.correlation_window_size)
    bm.setPreFilterType(cv2.StereoBM_PREFILTER_XSOBEL)
    bm.setPreFilterSize(params.prefilter_size)
    bm.setPreFilterCap(params.prefilter_cap)
    bm.setMinDisparity(params.min_disparity)
    bm.setTextureThreshold(params.texture_threshold)
    bm.setUniquenessRatio(round(params.uniqueness_ratio))
    bm.setSpeckleWindowSize(params.speckle_size)
    bm.setSpeckleRange(params.speckle_range)
    bm.setDisp12MaxDiff(params.disp12_max_diff if params.disp12_max_diff > 0 else -1)  # 0: off, as stereo_image_proc
    return OpenCVMatcher(bm, params.min_disparity)


def sgbm_disp12_max_diff(params: StereoParams) -> int:
    """disp12_max_diff as StereoSGBM takes it. SGBM turns any value <= 0 into 1, so -1 (check off) becomes
    a tolerance as wide as the disparity range, which no two disparities of the range exceed; 0 goes
    through as stereo_image_proc passes it (a 1 px check)."""
    return params.disparity_range if params.disp12_max_diff < 0 else params.disp12_max_diff


def opencv_sgbm(params: StereoParams, speckle_size: int) -> cv2.StereoSGBM:
    return cv2.StereoSGBM.create(
        minDisparity=params.min_disparity,
        numDisparities=params.disparity_range,
        blockSize=params.correlation_window_size,
        P1=round(params.P1),
        P2=round(params.P2),
        disp12MaxDiff=sgbm_disp12_max_diff(params),
        preFilterCap=params.prefilter_cap,
        uniquenessRatio=round(params.uniqueness_ratio),
        speckleWindowSize=speckle_size,
        speckleRange=params.speckle_range,
        mode=params.sgbm_mode,
    )


ONE_CORE_SGBM_MODES = (0, 1)  # SGBM and HH; SGBM_3WAY and HH4 spread one image over OpenCV's threads
STRIP_OVERLAP = 48  # rows each half reaches into the other


@functools.cache
def _lower_halves() -> ThreadPoolExecutor:
    """The threads that match lower halves, shared by every StripSGBM (one per frame matched at once)."""
    return ThreadPoolExecutor(max_workers=4, thread_name_prefix="sgbm_lower_half")


class StripSGBM:
    """OpenCV SGBM in its SGBM and HH modes, on two cores.

    Those two modes aggregate on the calling thread only. This matches the upper and the lower half
    of the image at once (the lower one on a helper thread), each reaching STRIP_OVERLAP rows into the
    other, joins them, and removes speckles over the whole image as OpenCV does inside `compute`.
    Semi-global paths restarted at a half's edge agree with the whole-image ones again within the
    overlap: the joined disparity equals OpenCV's whole-image result bit for bit on every scene tested
    (test/test_strip_sgbm.py), 1.3-1.8x sooner on two cores (bench/parallel_matching.py). Images too
    low to split are matched whole.
    """

    def __init__(self, params: StereoParams) -> None:
        self._upper, self._lower = opencv_sgbm(params, 0), opencv_sgbm(params, 0)  # speckles: after joining
        self._params = params

    def compute(self, left: np.ndarray, right: np.ndarray) -> MatchResult:
        height = left.shape[0]
        if height < 4 * STRIP_OVERLAP:
            raw = self._upper.compute(left, right)
        else:
            middle, overlap = height // 2, STRIP_OVERLAP
            lower = _lower_halves().submit(self._lower.compute, left[middle - overlap :], right[middle - overlap :])
            raw = np.empty(left.shape[:2], np.int16)
            raw[:middle] = self._upper.compute(left[: middle + overlap], right[: middle + overlap])[:middle]
            raw[middle:] = lower.result()[overlap:]
        p = self._params
        if p.speckle_size > 0:
            cv2.filterSpeckles(raw, (p.min_disparity - 1) * 16, p.speckle_size, 16 * p.speckle_range)
        return MatchResult(fixed_point_to_float(raw, p.min_disparity))


def create_sgbm(params: StereoParams) -> Matcher:
    if params.sgbm_mode in ONE_CORE_SGBM_MODES:
        return StripSGBM(params)
    return OpenCVMatcher(opencv_sgbm(params, params.speckle_size), params.min_disparity)


def min_image_size(params: StereoParams) -> tuple[int, int]:
    """(width, height) below which a matcher cannot work: StereoSGBM crashes the process on narrower
    images and StereoBM raises on lower ones, so the pipeline refuses them first (measured, OpenCV 5)."""
    width = max(params.min_disparity, 0) + params.disparity_range + params.correlation_window_size
    return width, params.correlation_window_size + 1


class CensusSGMMatcher:
    """Our own core (census cost, 8-path semi-global aggregation, LR check, sub-pixel, confidence).

    numba compiles it on first use (then loads it from the cache), so it is imported only when chosen.
    """

    def __init__(self, params: StereoParams) -> None:
        self._params = params

    def compute(self, left: np.ndarray, right: np.ndarray) -> MatchResult:
        from stereo_depth.core.census_sgm import census_sgm

        p = self._params
        disparity, confidence = census_sgm(
            left,
            right,
            min_disparity=p.min_disparity,
            num_disparities=p.disparity_range,
            window_size=p.correlation_window_size,
            P1=p.P1,
            P2=p.P2,
            uniqueness_ratio=p.uniqueness_ratio,
            disp12_max_diff=p.disp12_max_diff,
            speckle_size=p.speckle_size,
            speckle_range=p.speckle_range,
            paths=p.census_paths,
        )
        return MatchResult(disparity, confidence)


MATCHERS: dict[str, Callable[[StereoParams], Matcher]] = {
    "bm": create_bm,
    "sgbm": create_sgbm,
    "census_sgm": CensusSGMMatcher,
}


def create_matcher(params: StereoParams) -> Matcher:
    return MATCHERS[params.matcher](params)
