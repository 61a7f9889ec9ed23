"""`downsample_output: processed`: outputs at the matched size, with a calibration that fits them.

The Middlebury artl scene has different cx for its two cameras, so a wrongly scaled offset shows.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from stereo_depth.core.params import make_params
from stereo_depth.core.pipeline import StereoPipeline, output_params
from stereo_depth.errors import ParameterError
from stereo_depth.formats.scenes import load_scene

from conftest import SCENES


def run(**overrides: object) -> Any:
    """The processed artl frame (Any: every optional output of it is filled in here)."""
    scene = load_scene(SCENES / "artl")
    pipeline = StereoPipeline(make_params("fast", {"fill_holes": False, **overrides}))
    left_info, right_info = scene.camera_infos("left")
    return pipeline.process(scene.left, scene.right, pipeline.camera_for(left_info, right_info))


def test_processed_outputs_have_the_matched_size_and_a_calibration_scaled_about_pixel_centres() -> None:
    full, small = run(), run(downsample_output="processed")
    height, width = full.disparity.shape
    assert small.disparity.shape == small.depth.shape == small.left_rect.shape == (height // 2, width // 2)
    assert small.points.shape == (height // 2, width // 2, 3)
    assert (small.camera.width, small.camera.height) == (width // 2, height // 2)
    assert small.camera.fx == pytest.approx(full.camera.fx / 2)
    assert small.camera.cx_left == pytest.approx((full.camera.cx_left + 0.5) / 2 - 0.5)
    assert small.camera.disparity_offset == pytest.approx(full.camera.disparity_offset / 2)
    assert small.camera.baseline == pytest.approx(full.camera.baseline)
    # the full-size output is the processed one enlarged (nearest; at odd sizes a sample may be the
    # neighbour), so the depths agree where both are valid
    sampled = full.depth[: 2 * small.depth.shape[0] : 2, : 2 * small.depth.shape[1] : 2]
    both = np.isfinite(small.depth) & np.isfinite(sampled)
    assert both.mean() > 0.2  # BM at 1/2 size without hole filling on a small scene
    relative = np.abs(small.depth[both] - sampled[both]) / sampled[both]
    assert np.median(relative) < 0.005 and np.mean(relative < 0.02) > 0.9
    # points project back onto their own pixel in the small image
    v, u = np.nonzero(both)
    x, y, z = (small.points[v, u, i].astype(np.float64) for i in range(3))
    np.testing.assert_allclose(small.camera.fx * x / z + small.camera.cx_left, u, atol=1e-3)
    np.testing.assert_allclose(small.camera.fy * y / z + small.camera.cy, v, atol=1e-3)


def test_disparity_message_parameters_follow_the_output_size() -> None:
    params = make_params("fast", {"downsample_output": "processed"})
    described = output_params(params)
    assert (described.disparity_range, described.downsample) == (32, 1)  # delta_d 1/16 of a small pixel
    full = make_params("fast")
    assert output_params(full) is full


def test_unknown_output_size_is_refused_with_the_choices() -> None:
    with pytest.raises(ParameterError, match="downsample_output 'half' is unknown; choose one of full, processed"):
        make_params("fast", {"downsample_output": "half"})
