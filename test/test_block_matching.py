"""Our BM kernels must give exactly OpenCV's StereoBM disparity: stereo_image_proc users switching to us
expect its numbers, pixel for pixel, whatever the parameters and the image's shape."""

from __future__ import annotations

import itertools

import cv2
import numpy as np
import pytest

from stereo_depth.core.block_matching import WIDE_VECTOR_BITS, BlockMatcher, numba_bm_applies
from stereo_depth.core.matching import Halves, OpenCVBands, create_matcher, opencv_bm, whole_image
from stereo_depth.core.params import StereoParams, make_params
from stereo_depth.core.simd import numba_target

from conftest import grey_pairs


def opencv_raw(params: StereoParams, left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """cv2.StereoBM's int16 disparity before its speckle filter (which `Halves` runs for both matchers)."""
    before = cv2.getNumThreads()
    cv2.setNumThreads(1)  # OpenCV's result does not depend on its stripes; this keeps the test quick to read
    try:
        return np.asarray(opencv_bm(params, 0).compute(left, right))
    finally:
        cv2.setNumThreads(before)


def ours_raw(params: StereoParams, left: np.ndarray, right: np.ndarray) -> np.ndarray:
    matcher = BlockMatcher(params)
    return matcher.band(matcher.prepare(left, right), 0, left.shape[0])


PAIRS = grey_pairs()

# (window, disparity_range, min_disparity, texture_threshold, uniqueness_ratio, prefilter_cap): every value
# each parameter takes somewhere, on both parities of the height and width (cropped by one row / column)
SETTINGS = [
    (15, 64, 0, 10, 15.0, 31),  # stereo_image_proc's defaults
    (5, 16, 0, 0, 0.0, 31),
    (9, 48, -4, 50, 5.0, 15),
    (21, 128, 0, 10, 30.0, 31),
    (7, 32, -8, 10, 15.0, 1),
    (11, 80, -40, 200, 60.0, 20),
]


@pytest.mark.parametrize("setting", SETTINGS, ids=[f"w{s[0]}_n{s[1]}_min{s[2]}" for s in SETTINGS])
@pytest.mark.parametrize(("name", "left", "right"), PAIRS, ids=[p[0] for p in PAIRS])
def test_our_kernels_give_opencvs_stereobm(
    setting: tuple[int, int, int, int, float, int], name: str, left: np.ndarray, right: np.ndarray
) -> None:
    window, disparities, min_disparity, texture, uniqueness, cap = setting
    params = make_params(
        "stereo_image_proc",
        {
            "correlation_window_size": window,
            "disparity_range": disparities,
            "min_disparity": min_disparity,
            "texture_threshold": texture,
            "uniqueness_ratio": uniqueness,
            "prefilter_cap": cap,
        },
    )
    assert numba_bm_applies(params)
    for rows, columns in itertools.product((0, 1), (0, 1)):
        crop_l, crop_r = (i[: i.shape[0] - rows, : i.shape[1] - columns] for i in (left, right))
        expected = opencv_raw(params, crop_l, crop_r)
        got = ours_raw(params, crop_l, crop_r)
        assert (expected > (min_disparity - 1) * 16).mean() > 0.05  # a test of matches, not of invalid pixels
        np.testing.assert_array_equal(got, expected, err_msg=f"{name} cropped by {rows} row(s), {columns} column(s)")


def test_a_band_equals_those_rows_of_the_whole_pair() -> None:
    """The node matches the upper and the lower half on two cores; each band's windows reach beyond it."""
    _, left, right = PAIRS[0]
    params = make_params("stereo_image_proc")
    matcher = BlockMatcher(params)
    frame = matcher.prepare(left, right)
    whole = matcher.band(frame, 0, left.shape[0])
    for start, stop in ((0, 7), (5, 200), (200, left.shape[0]), (left.shape[0] - 3, left.shape[0])):
        np.testing.assert_array_equal(matcher.band(frame, start, stop), whole[start:stop])


@pytest.mark.parametrize(
    "overrides",
    [{"disp12_max_diff": 1}, {"prefilter_cap": 40}, {"correlation_window_size": 23}, {"min_disparity": 4}],
    ids=["left_right_check", "wide_prefilter_cap", "wide_window", "positive_min_disparity"],
)
def test_where_our_kernels_do_not_apply_opencv_matches(overrides: dict[str, int]) -> None:
    """OpenCV's 32-bit sums, its left-right check and its writes past a row's end with min_disparity > 0 are
    not ours: it matches those itself, still exactly."""
    params = make_params("stereo_image_proc", overrides)
    assert not numba_bm_applies(params)
    matcher = create_matcher(params)
    assert isinstance(matcher, Halves) and isinstance(vars(matcher)["_bands"], OpenCVBands)
    _, left, right = PAIRS[1]
    expected = whole_image(params).compute(left, right).disparity
    np.testing.assert_array_equal(matcher.compute(left, right).disparity, expected)


@pytest.mark.skipif(numba_target().vector_bits < WIDE_VECTOR_BITS, reason="OpenCV's BM is as fast at 128 bits")
def test_stereo_image_procs_defaults_use_our_kernels() -> None:
    params = make_params("stereo_image_proc")
    matcher = create_matcher(params)
    assert isinstance(matcher, Halves) and isinstance(vars(matcher)["_bands"], BlockMatcher)
    assert params.disp12_max_diff <= 0  # the profile's left-right check is off, as stereo_image_proc's BM
