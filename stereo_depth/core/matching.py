"""Matching cores behind one interface, chosen by name.

A core turns a rectified grey pair into float32 disparity (left reference, d = x_left - x_right,
NaN = invalid) and optionally a confidence in [0, 1]. The OpenCV cores keep their matcher object
between frames; a parameter change builds a new core, never mutates one in use.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import cv2
import numpy as np

from stereo_depth.core.block_matching import BlockMatcher, numba_bm_applies, use_our_bm
from stereo_depth.core.params import StereoParams
from stereo_depth.core.speckles import SplitSpeckleFilter
from stereo_depth.core.threads import opencv_threads, other_core

if TYPE_CHECKING:
    from stereo_depth.core.too_near import CoarseSearch


@dataclass
class MatchResult:
    disparity: np.ndarray
    confidence: np.ndarray | None = None
    excluded: np.ndarray | None = None  # bool: invalidated by a detector; no filter may refill these
    too_near: np.ndarray | None = None  # bool: nearer than the disparity range can see (core/too_near.py)
    coarse: CoarseSearch | None = None  # too-near detection's coarse search, at its own size


class Matcher(Protocol):
    def compute(self, left: np.ndarray, right: np.ndarray) -> MatchResult:
        """left/right: rectified uint8 grey images of equal size."""
        ...


def fixed_point_to_float(raw: np.ndarray, min_disparity: int, out: np.ndarray | None = None) -> np.ndarray:
    """OpenCV's int16 disparity (x16) to float32 pixels (into `out` when given); below min_disparity means
    invalid."""
    disparity: np.ndarray = np.multiply(raw, np.float32(1.0 / 16.0), out=out, dtype=np.float32)
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


def opencv_bm(params: StereoParams, speckle_size: int) -> cv2.StereoBM:
    bm = cv2.StereoBM.create(params.disparity_range, params.correlation_window_size)
    bm.setPreFilterType(cv2.StereoBM_PREFILTER_XSOBEL)
    bm.setPreFilterSize(params.prefilter_size)
    bm.setPreFilterCap(params.prefilter_cap)
    bm.setMinDisparity(params.min_disparity)
    bm.setTextureThreshold(params.texture_threshold)
    bm.setUniquenessRatio(round(params.uniqueness_ratio))
    bm.setSpeckleWindowSize(speckle_size)
    bm.setSpeckleRange(params.speckle_range)
    bm.setDisp12MaxDiff(params.disp12_max_diff if params.disp12_max_diff > 0 else -1)  # 0: off, as stereo_image_proc
    return bm


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
STRIP_OVERLAP = 48  # rows each half reaches into the other (semi-global paths need them to agree again)


class Bands(Protocol):
    """A matcher that gives OpenCV's int16 disparity (1/16 px) of a band of rows of a pair, on any thread."""

    def prepare(self, left: np.ndarray, right: np.ndarray) -> Any:
        """Once per frame, before its bands: what `band` reads."""
        ...

    def band(self, frame: Any, start: int, stop: int, half: int) -> np.ndarray:
        """Rows [start, stop) of the pair's disparity; `half` (0 upper, 1 lower) picks the matcher object."""
        ...


class OpenCVBands:
    """An OpenCV matcher on a band of rows, reaching `overlap` rows beyond it on either side (from an even
    row: BM's last valid row depends on the parity of the image's height), one object per half (OpenCV's
    matchers keep working buffers between calls)."""

    def __init__(self, matchers: tuple[cv2.StereoMatcher, cv2.StereoMatcher], overlap: int) -> None:
        self._matchers = matchers
        self._overlap = overlap

    def prepare(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return left, right

    def band(self, frame: tuple[np.ndarray, np.ndarray], start: int, stop: int, half: int) -> np.ndarray:
        left, right = frame
        height = left.shape[0]
        first = (start - self._overlap) & ~1 if start > 0 else 0
        last = min(height, 2 * stop - ((stop - self._overlap) & ~1)) if stop < height else height
        matched: np.ndarray = self._matchers[half].compute(left[first:last], right[first:last])
        return matched[start - first : stop - first]


class Halves:
    """A matcher on two cores: the upper and the lower half of the image at once (the lower one on a helper
    thread kept off the caller's core, core/threads.py `OtherCore`), then each half's speckles removed and
    its disparity converted on the same thread (core/speckles.py: the halves' speckle filters give what one
    filter over the whole image gives, as OpenCV runs it inside `compute`).

    - BM: our kernels (core/block_matching.py), which match a band of rows of the whole pair; where they do
      not apply, OpenCV's on each half. OpenCV spreads an image over its threads in stripes of at least
      ~200 rows, so a VGA frame is 3 stripes on 2 cores, one of them running two; each half runs on one
      OpenCV thread instead (1.45x sooner than the whole image on two threads, anchor frames, 640x480,
      64 disparities), reaching the window's and the prefilter's reach into the other.
    - SGBM and HH aggregate on the calling thread only. Semi-global paths restarted at a half's edge
      agree with the whole-image ones again within STRIP_OVERLAP rows.
    The joined disparity equals OpenCV's whole-image result bit for bit on every scene tested
    (test/test_halves.py). Images lower than `min_height`, and frames given one thread (core/threads.py:
    a fleet worker's share, or a node matching two frames at once), are matched whole.
    """

    def __init__(self, bands: Bands, params: StereoParams, speckle_range: int, min_height: int) -> None:
        self._bands = bands
        self._speckle_range = speckle_range  # in the matcher's unit: 1/16 px for BM, px for SGBM
        self._min_height = min_height
        self._params = params

    def compute(self, left: np.ndarray, right: np.ndarray) -> MatchResult:
        p = self._params
        height = left.shape[0]
        split = height >= self._min_height and cv2.getNumThreads() >= 2
        middle = height // 2 if split else height
        raw = np.empty(left.shape[:2], np.int16)
        disparity = np.empty(left.shape[:2], np.float32)
        speckles = SplitSpeckleFilter(raw, middle, (p.min_disparity - 1) * 16, p.speckle_size, self._speckle_range)
        frame = self._bands.prepare(left, right)

        def finish(start: int, stop: int, half: int) -> None:
            raw[start:stop] = self._bands.band(frame, start, stop, half)
            speckles.filter_rows(start, stop)
            fixed_point_to_float(raw[start:stop], p.min_disparity, disparity[start:stop])

        if not split:
            finish(0, height, 0)
            return MatchResult(disparity)
        with opencv_threads(1):  # one core per half: BM's own stripes would run two of them on one core
            lower = other_core("lower_half").submit(lambda: finish(middle, height, 1))
            finish(0, middle, 0)
            lower.result()
        changed = speckles.join()
        if changed is not None:
            first, last = changed
            fixed_point_to_float(raw[first:last], p.min_disparity, disparity[first:last])
        return MatchResult(disparity)


def whole_image(params: StereoParams) -> OpenCVMatcher:
    """OpenCV's BM or SGBM called on the whole image, as a script would: what `Halves` equals."""
    build = opencv_bm if params.matcher == "bm" else opencv_sgbm
    return OpenCVMatcher(build(params, params.speckle_size), params.min_disparity)


def create_bm(params: StereoParams, *, our_kernels: bool | None = None) -> Matcher:
    """Our BM kernels where they apply and win (core/block_matching.py `use_our_bm`), else OpenCV's; benches
    compare the two with `our_kernels` True (ours wherever they apply) or False (OpenCV's). StereoBM takes
    its speckle range in 1/16 px (StereoSGBM in pixels), as stereo_image_proc passes it."""
    reach = params.correlation_window_size // 2 + params.prefilter_size // 2 + 1
    ours = use_our_bm(params) if our_kernels is None else our_kernels and numba_bm_applies(params)
    bands = BlockMatcher(params) if ours else OpenCVBands((opencv_bm(params, 0), opencv_bm(params, 0)), reach)
    return Halves(bands, params, params.speckle_range, 4 * reach)


def create_sgbm(params: StereoParams) -> Matcher:
    if params.sgbm_mode in ONE_CORE_SGBM_MODES:
        bands = OpenCVBands((opencv_sgbm(params, 0), opencv_sgbm(params, 0)), STRIP_OVERLAP)
        return Halves(bands, params, 16 * params.speckle_range, 4 * STRIP_OVERLAP)
    return OpenCVMatcher(opencv_sgbm(params, params.speckle_size), params.min_disparity)


def min_image_size(params: StereoParams) -> tuple[int, int]:
    """(width, height) below which a matcher cannot work: StereoSGBM crashes the process on narrower
    images and StereoBM raises on lower ones, so the pipeline refuses them first (measured, OpenCV 5)."""
    width = max(params.min_disparity, 0) + params.disparity_range + params.correlation_window_size
    return width, params.correlation_window_size + 1


class CensusSGMMatcher:
    """Our own core (census cost, 6-path semi-global aggregation (census_paths), LR check, sub-pixel, confidence).

    numba compiles it on first use (then loads it from the cache), so it is imported only when chosen.
    """

    def __init__(self, params: StereoParams) -> None:
        self._params = params
        self.step_ms: dict[str, float] = {}  # the last frame's time per step of census_sgm

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
            timings=self.step_ms,
        )
        return MatchResult(disparity, confidence)


MATCHERS: dict[str, Callable[[StereoParams], Matcher]] = {
    "bm": create_bm,
    "sgbm": create_sgbm,
    "census_sgm": CensusSGMMatcher,
}


def create_matcher(params: StereoParams) -> Matcher:
    return MATCHERS[params.matcher](params)
