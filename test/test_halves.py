"""OpenCV's BM and SGBM's one-core modes matched as two overlapping halves at once must give exactly what
OpenCV gives for the whole image: stereo_image_proc users switching to us expect its disparity."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from stereo_depth.core import matching
from stereo_depth.core.matching import STRIP_OVERLAP, Halves, OpenCVMatcher, create_matcher, whole_image
from stereo_depth.core.params import make_params
from stereo_depth.core.threads import use_threads

from conftest import grey_pairs

PAIRS = grey_pairs()  # conftest.py


@pytest.mark.parametrize("mode", [0, 1], ids=["SGBM", "HH"])
@pytest.mark.parametrize(("name", "left", "right"), PAIRS, ids=[p[0] for p in PAIRS])
def test_halves_equal_opencv_on_the_whole_image(mode: int, name: str, left: np.ndarray, right: np.ndarray) -> None:
    params = make_params("stereo_image_proc", {"stereo_algorithm": 1, "sgbm_mode": mode})
    matcher = create_matcher(params)
    assert isinstance(matcher, Halves) and left.shape[0] >= 4 * STRIP_OVERLAP  # the halves are used
    whole = whole_image(params).compute(left, right)
    halves = matcher.compute(left, right).disparity
    assert np.isfinite(halves).mean() > 0.3
    np.testing.assert_array_equal(halves, whole.disparity)


@pytest.mark.parametrize("rows", [0, 1], ids=["as_is", "one_row_less"])  # both parities of the image height
@pytest.mark.parametrize("check", [0, 1], ids=["our_kernels", "opencv_left_right_check"])  # test_block_matching.py
@pytest.mark.parametrize(("name", "left", "right"), PAIRS, ids=[p[0] for p in PAIRS])
def test_bm_halves_equal_opencv_on_the_whole_image(
    rows: int, check: int, name: str, left: np.ndarray, right: np.ndarray
) -> None:
    left, right = left[: left.shape[0] - rows], right[: right.shape[0] - rows]
    params = make_params("stereo_image_proc", {"disp12_max_diff": check})  # BM with its speckle filter
    matcher = create_matcher(params)
    assert isinstance(matcher, Halves) and params.speckle_size > 0
    whole = whole_image(params).compute(left, right)
    halves = matcher.compute(left, right).disparity
    assert np.isfinite(halves).mean() > 0.3
    np.testing.assert_array_equal(halves, whole.disparity)


def test_multi_core_modes_and_small_images_use_opencv_directly() -> None:
    params = make_params("default")
    assert params.sgbm_mode == 2 and isinstance(create_matcher(params), OpenCVMatcher)
    _, left, right = PAIRS[0]
    params = dataclasses.replace(make_params("stereo_image_proc", {"stereo_algorithm": 1}), disparity_range=32)
    small_l, small_r = left[: 3 * STRIP_OVERLAP], right[: 3 * STRIP_OVERLAP]
    whole = whole_image(params).compute(small_l, small_r)
    np.testing.assert_array_equal(create_matcher(params).compute(small_l, small_r).disparity, whole.disparity)


def test_a_frame_given_one_thread_is_matched_whole_on_that_thread(monkeypatch: pytest.MonkeyPatch) -> None:
    """A fleet worker's share of one core, or a node matching two frames at once: no helper thread."""
    _, left, right = PAIRS[0]
    params = make_params("stereo_image_proc")
    whole = whole_image(params).compute(left, right)
    monkeypatch.setattr(matching, "other_core", lambda _: pytest.fail("a helper thread was used"))
    before = use_threads(0)
    try:
        assert use_threads(1) == 1
        np.testing.assert_array_equal(create_matcher(params).compute(left, right).disparity, whole.disparity)
    finally:
        use_threads(before)
