"""The spatial filter (spatial_filter): replaces wrong matches by their surface's value, smooths the disparity
within a surface, never across a depth edge, and never changes which pixels have a disparity."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from stereo_depth.core.metrics import accuracy
from stereo_depth.core.params import make_params
from stereo_depth.core.pipeline import StereoPipeline
from stereo_depth.core.spatial import SpatialSettings, spatial_filter
from stereo_depth.formats.scenes import load_scene

SCENES = Path(__file__).resolve().parent / "data" / "scenes"
SETTINGS = SpatialSettings()
FLAT = np.zeros((120, 160), np.uint8)  # an image without texture: the disparity alone guides the filter


def noisy_plane(rng: np.random.Generator, shape: tuple[int, int] = (120, 160)) -> tuple[np.ndarray, np.ndarray]:
    """A slanted plane (20 to 36 px across) and the same with 0.3 px of matching noise."""
    rows, columns = np.mgrid[: shape[0], : shape[1]].astype(np.float32)
    plane = np.float32(20.0) + columns * np.float32(0.1) + rows * np.float32(0.02)
    return plane, (plane + rng.normal(0.0, 0.3, shape)).astype(np.float32)


def test_noise_on_a_plane_is_smoothed_without_bending_the_plane() -> None:
    plane, noisy = noisy_plane(np.random.default_rng(1))
    error_before = np.abs(noisy - plane)
    error_after = np.abs(spatial_filter(noisy, SETTINGS, FLAT) - plane)
    assert error_after.mean() < 0.5 * error_before.mean()
    inner = np.s_[8:-8, 8:-8]  # away from the borders, where the passes start
    assert abs(float((spatial_filter(noisy, SETTINGS, FLAT) - plane)[inner].mean())) < 0.02  # no slant-induced bias


def test_a_depth_edge_is_never_crossed() -> None:
    """Foreground (40 px) on background (20 px), both noisy: every pixel stays within its own side's range."""
    rng = np.random.default_rng(2)
    disparity = np.full((100, 100), 20.0, np.float32)
    disparity[30:70, 30:70] = 40.0
    disparity[48:52, 10:90] = 40.0  # a thin pole
    foreground = disparity > 30
    grey = np.where(foreground, 150, 100).astype(np.uint8)  # the image shows the object
    disparity += rng.normal(0.0, 0.3, disparity.shape).astype(np.float32)
    out = spatial_filter(disparity, SETTINGS, grey)
    for side in (foreground, ~foreground):
        assert out[side].min() >= disparity[side].min() and out[side].max() <= disparity[side].max()
    assert np.abs(out[foreground] - 40.0).max() < 1.5 and np.abs(out[~foreground] - 20.0).max() < 1.5


def test_a_wrong_match_on_a_surface_takes_the_surface_value() -> None:
    """Isolated wrong matches (one pixel, a 2x2 patch) on a slanted plane, far beyond the smoothing's
    depth-edge step: the outlier pass puts them back on the plane."""
    plane, _ = noisy_plane(np.random.default_rng(3))
    disparity = plane.copy()
    disparity[40, 50] += 12.0
    disparity[80:82, 100:102] -= 9.0
    out = spatial_filter(disparity, SETTINGS, FLAT)
    assert abs(out[40, 50] - plane[40, 50]) < 0.5
    assert np.abs(out[80:82, 100:102] - plane[80:82, 100:102]).max() < 0.5
    np.testing.assert_array_equal(np.isnan(out), np.isnan(disparity))


def test_a_thin_real_structure_survives() -> None:
    """A pole 3 px wide, nearer than the wall behind it, that the image shows: the outlier pass keeps it."""
    disparity = np.full((120, 160), 20.0, np.float32)
    disparity[:, 70:73] = 35.0
    grey = np.full(disparity.shape, 90, np.uint8)
    grey[:, 70:73] = 160
    out = spatial_filter(disparity, SETTINGS, grey)
    np.testing.assert_allclose(out[:, 70:73], 35.0, atol=0.5)
    np.testing.assert_allclose(out[:, 60:68], 20.0, atol=0.5)


def test_holes_stay_holes_and_no_hole_spreads() -> None:
    """On a real disparity with holes (SGBM on Cones): the valid pixels are exactly the same afterwards."""
    scene = load_scene(SCENES / "cones")
    params = make_params("default", {"disparity_range": scene.disparity_range()})
    disparity = StereoPipeline(params).match(scene.left, scene.right, None, rectified=True).disparity
    assert 0.02 < np.isnan(disparity).mean() < 0.5
    out = spatial_filter(disparity, SETTINGS, cv2.cvtColor(scene.left, cv2.COLOR_BGR2GRAY))
    np.testing.assert_array_equal(np.isnan(out), np.isnan(disparity))


def test_the_pipeline_filters_within_surfaces_and_lowers_the_error_on_a_real_scene() -> None:
    scene = load_scene(SCENES / "cones")
    assert scene.gt is not None
    results = [
        StereoPipeline(make_params("default", {"disparity_range": scene.disparity_range(), "spatial_filter": on}))
        .match(scene.left, scene.right, None, rectified=True)
        .disparity
        for on in (False, True)
    ]
    without, with_filter = (accuracy(d, scene.gt, scene.mask) for d in results)
    np.testing.assert_array_equal(np.isnan(results[1]), np.isnan(results[0]))
    assert with_filter.epe < without.epe
    assert with_filter.bad2_est <= without.bad2_est + 0.002
