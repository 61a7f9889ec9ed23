"""disp12_max_diff means one thing for every matcher: -1 switches the left-right check off, N >= 1
allows N px, and 0 gives what stereo_image_proc gives with its own settings (its YAML says 0; it
passes the value to OpenCV's SGBM, which makes it 1 px, and never to BM, whose check stays off)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from stereo_depth.core.params import make_params
from stereo_depth.core.pipeline import StereoPipeline
from stereo_depth.errors import ParameterError
from stereo_depth.formats.scenes import load_scene

from conftest import SCENES

SCENE = load_scene(SCENES / "cones")
LEFT, RIGHT = (cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) for image in (SCENE.left, SCENE.right))


def disparity(matcher: str, disp12_max_diff: int, **overrides: object) -> np.ndarray:
    params = make_params("default", {"matcher": matcher, "disp12_max_diff": disp12_max_diff, **overrides})
    return StereoPipeline(params).match(LEFT, RIGHT, None, rectified=True).disparity


def valid(matcher: str, disp12_max_diff: int) -> int:
    return int(np.isfinite(disparity(matcher, disp12_max_diff)).sum())


@pytest.mark.parametrize("mode", [0, 2], ids=["SGBM (two halves)", "SGBM_3WAY"])
@pytest.mark.parametrize("disp12_max_diff", [0, 3])
def test_sgbm_gives_plain_opencv_sgbm_bit_for_bit(disp12_max_diff: int, mode: int) -> None:
    """What a stereo_image_proc user gets from cv2.StereoSGBM with the same settings, 0 included, with
    near_detection off (on, the pixels too near for the range are invalid)."""
    ours = disparity("sgbm", disp12_max_diff, sgbm_mode=mode, near_detection=False)
    p = make_params("default", {"sgbm_mode": mode})
    plain = cv2.StereoSGBM.create(
        minDisparity=p.min_disparity,
        numDisparities=p.disparity_range,
        blockSize=p.correlation_window_size,
        P1=round(p.P1),
        P2=round(p.P2),
        disp12MaxDiff=disp12_max_diff,
        preFilterCap=p.prefilter_cap,
        uniquenessRatio=round(p.uniqueness_ratio),
        speckleWindowSize=p.speckle_size,
        speckleRange=p.speckle_range,
        mode=mode,
    ).compute(LEFT, RIGHT)
    expected = plain.astype(np.float32) / np.float32(16.0)
    expected[plain < p.min_disparity * 16] = np.nan
    np.testing.assert_array_equal(ours, expected)


@pytest.mark.parametrize("matcher", ["sgbm", "census_sgm"])
def test_minus_one_switches_the_check_off(matcher: str) -> None:
    """More pixels survive with the check off than with the strictest check, for the semi-global cores
    too (OpenCV's SGBM cannot be switched off by its own value: it turns -1 into 1)."""
    assert valid(matcher, -1) > valid(matcher, 0)
    assert valid(matcher, -1) > valid(matcher, 1)


def test_bm_at_zero_has_the_check_off_as_stereo_image_proc() -> None:
    """stereo_image_proc never passes disp12_max_diff to BM: its 0 leaves the check off, as -1 does."""
    np.testing.assert_array_equal(disparity("bm", 0), disparity("bm", -1))
    assert valid("bm", -1) > valid("bm", 1)


def test_range_admits_minus_one_only() -> None:
    assert make_params("default", {"disp12_max_diff": -1}).disp12_max_diff == -1
    with pytest.raises(ParameterError, match=r"disp12_max_diff -2 is outside \[-1, 128\]"):
        make_params("default", {"disp12_max_diff": -2})
