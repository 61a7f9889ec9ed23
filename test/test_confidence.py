"""Every matcher says how sure it is: on real Middlebury scenes the confident pixels are the right ones,
one threshold keeps about the same share of pixels whichever matcher runs, and a threshold of 0
leaves OpenCV's disparity as it was."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from stereo_depth.core.matching import whole_image
from stereo_depth.core.metrics import accuracy, evaluation_mask
from stereo_depth.core.params import make_params
from stereo_depth.core.pipeline import StereoPipeline
from stereo_depth.formats.scenes import Scene, load_scene

from conftest import SCENES

# each matcher as the profiles run it, without what would change its valid pixels after matching
MATCHER_PROFILES: dict[str, tuple[str, dict[str, Any]]] = {
    "sgbm": ("default", {}),
    "bm": ("fast", {"fill_holes": False, "downsample": 1}),
    "census_sgm": ("quality", {"confidence_threshold": 0.0}),
}


def matched(scene: Scene, matcher: str, **overrides: Any) -> tuple[np.ndarray, np.ndarray]:
    profile, values = MATCHER_PROFILES[matcher]
    params = make_params(profile, {**values, "disparity_range": scene.disparity_range(), **overrides})
    result = StereoPipeline(params).match(scene.left, scene.right, None, rectified=True)
    assert result.confidence is not None, f"{matcher} gives no confidence"
    return result.disparity, result.confidence


@pytest.mark.parametrize("matcher", sorted(MATCHER_PROFILES))
def test_confident_pixels_are_the_right_ones_for_every_matcher(matcher: str) -> None:
    """At 0.5 each matcher keeps about the same share of its valid pixels (census_sgm's ~78 %), and
    those have well under the bad-2 of all of them, on each scene."""
    for name in ("artl", "cones"):
        scene = load_scene(SCENES / name)
        assert scene.gt is not None
        disparity, confidence = matched(scene, matcher)
        valid = np.isfinite(disparity)
        assert np.all(confidence[~valid] == 0.0) and confidence.min() >= 0.0 and confidence.max() <= 1.0
        counted = valid & evaluation_mask(scene.gt, scene.mask)
        kept = float((confidence[counted] >= 0.5).mean())
        sure = np.where(confidence >= 0.5, disparity, np.nan)
        everything, confident = accuracy(disparity, scene.gt, scene.mask), accuracy(sure, scene.gt, scene.mask)
        assert 0.55 <= kept <= 0.95, (name, kept)
        assert confident.bad2_est < 0.7 * everything.bad2_est, (name, everything, confident)


@pytest.mark.parametrize("matcher", ["bm", "sgbm"])
def test_confidence_threshold_drops_the_unsure_pixels_of_opencv_matchers(matcher: str) -> None:
    scene = load_scene(SCENES / "cones")
    disparity, confidence = matched(scene, matcher)
    thresholded, _ = matched(scene, matcher, confidence_threshold=0.5)
    keep = confidence >= 0.5
    assert np.array_equal(thresholded[keep], disparity[keep], equal_nan=True)
    assert np.isnan(thresholded[~keep]).all() and keep.sum() < np.isfinite(disparity).sum()


@pytest.mark.parametrize("profile", ["default", "fast", "stereo_image_proc"])
def test_threshold_zero_leaves_opencvs_disparity_bit_identical(profile: str) -> None:
    """The confidence is computed beside the disparity and changes none of it."""
    scene = load_scene(SCENES / "cones")
    params = make_params(profile, {"fill_holes": False, "downsample": 1, "near_detection": False})
    result = StereoPipeline(params).match(scene.left, scene.right, None, rectified=True)
    grey = (result.left_rect, result.right_rect)
    assert result.confidence is not None
    assert np.array_equal(result.disparity, whole_image(params).compute(*grey).disparity, equal_nan=True)
