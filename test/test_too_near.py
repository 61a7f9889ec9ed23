"""A surface nearer than the disparity range can see never comes out far away: on real Middlebury scenes
run with a range their ground truth exceeds, those pixels are invalid in the disparity, hole filling
leaves them, they cast no clearing ray, and `near_points: range_limit` puts them in points2 at the
nearest depth the range sees; diagnostics say how many and how near."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
import pytest
from std_msgs.msg import Header

from stereo_depth.bag.types import rosbags_types
from stereo_depth.core.camera import StereoCamera
from stereo_depth.core.match_checks import MatchChecks
from stereo_depth.core.matching import MatchResult
from stereo_depth.core.metrics import evaluation_mask
from stereo_depth.core.params import make_params
from stereo_depth.core.pipeline import StereoPipeline
from stereo_depth.formats.scenes import load_scene
from stereo_depth.frames.decode import StereoFrame
from stereo_depth.frames.outputs import OutputState, geometry_outputs, nearest_matchable_depth, result_geometry
from stereo_depth.messages import cloud_to_arrays, make_header
from stereo_depth.options import OutputOptions
from stereo_depth.ros.diagnostics import RECENT_FRAMES, NodeDiagnostics

from conftest import SCENES

RANGE = 32  # Cones' and ArtL's ground truth reach 55 px
MARGIN = 2.0  # px: nearer than the top by this much is beyond it; output at the top it would be right within 2 px


def shares(profile: str, detection: bool) -> tuple[float, float]:
    """(share of the pixels beyond the range output valid, density of those within it) on Cones."""
    scene = load_scene(SCENES / "cones")
    assert scene.gt is not None
    params = make_params(profile, {"disparity_range": RANGE, "near_detection": detection})
    disparity = StereoPipeline(params).match(scene.left, scene.right, None, rectified=True).disparity
    counted, valid = evaluation_mask(scene.gt, scene.mask), np.isfinite(disparity)
    beyond, within = counted & (scene.gt >= RANGE + MARGIN), counted & (scene.gt < RANGE - MARGIN)
    return float(valid[beyond].mean()), float(valid[within].mean())


@pytest.mark.parametrize("profile", ["default", "quality", "fast"])
def test_a_surface_beyond_the_range_comes_out_invalid_not_farther(profile: str) -> None:
    """Without detection the matchers give a large share of those pixels a smaller (farther) disparity;
    with it few stay, and the pixels within the range keep their density."""
    beyond_off, within_off = shares(profile, detection=False)
    beyond_on, within_on = shares(profile, detection=True)
    assert beyond_off > 0.1 and beyond_on < 0.1, (beyond_off, beyond_on)
    # `fast` fills every hole without detection: it loses the holes the coarse search marks near the top
    # and the fills beside them that it does not back (on 10 Middlebury and KITTI scenes, 76 % of those
    # were wrong by more than 2 px)
    assert within_on > within_off - (0.12 if profile == "fast" else 0.04), (within_off, within_on)


def test_hole_filling_leaves_too_near_pixels_invalid() -> None:
    """`fast` fills every hole, but not the too-near pixels (they reach MatchResult.excluded), nor the
    few beside them whose fill the coarse search does not back."""
    scene = load_scene(SCENES / "cones")
    params = make_params("fast", {"disparity_range": RANGE})
    result = StereoPipeline(params).match(scene.left, scene.right, None, rectified=True)
    assert result.too_near is not None and result.too_near.mean() > 0.2
    assert np.isnan(result.disparity[result.too_near]).all()
    unfilled = np.isnan(result.disparity) & ~result.too_near
    assert unfilled.mean() < 0.05
    beside = cv2.dilate(result.too_near.view(np.uint8), np.ones((15, 15), np.uint8)) > 0  # 7 px: 3 at half size
    assert beside[unfilled].all()
    assert result.confidence is not None and np.all(result.confidence[result.too_near] == 0.0)


def test_a_sure_match_at_the_smallest_disparity_goes_where_the_coarse_search_sees_it_nearer() -> None:
    """A cost curve that wrapped round can put a near surface at the smallest disparity with full
    confidence (census_sgm did on Middlebury Dolls at 64): where the coarse search puts it well inside
    the range it is dropped, so it casts no clearing ray."""
    scene = load_scene(SCENES / "cones")
    assert scene.gt is not None
    shape = scene.gt.shape
    match = MatchResult(np.zeros(shape, np.float32), np.ones(shape, np.float32))
    left, right = (np.ascontiguousarray(image[:, :, 1]) for image in (scene.left, scene.right))
    MatchChecks(make_params("quality", {"disparity_range": RANGE})).apply(match, left, right)
    inside = evaluation_mask(scene.gt, scene.mask) & (scene.gt >= RANGE / 2) & (scene.gt < RANGE - MARGIN)
    assert inside.mean() > 0.2
    assert np.isfinite(match.disparity[inside]).mean() < 0.1


def test_hole_filling_does_not_carry_the_background_over_the_edge_of_a_too_near_surface() -> None:
    """Holes at the edge of a too-near surface that the coarse verdict (blocky to a coarse pixel) left
    out would be filled from the background beyond it: beside too-near pixels a fill stays only where
    the coarse search backs it. Without that rule `fast` outputs 0.048 of Cones' beyond-range pixels."""
    beyond_on, _ = shares("fast", detection=True)
    assert beyond_on < 0.035, beyond_on


def artl_outputs(near_points: str) -> tuple[dict[str, Any], StereoCamera, np.ndarray]:
    """Middlebury ArtL (ground truth to 55 px, calibrated) at RANGE through the offline and live path
    (`StereoPipeline.match`, then the frame's geometry outputs): (messages, calibration, ground truth)."""
    scene = load_scene(SCENES / "artl")
    assert scene.gt is not None
    pipeline = StereoPipeline(make_params("default", {"disparity_range": RANGE}))
    camera = pipeline.camera_for(*scene.camera_infos())
    result = pipeline.match(scene.left, scene.right, camera, rectified=True)
    types = rosbags_types()
    header = make_header(types, 1, "left")
    frame = StereoFrame(1, header, scene.left, scene.right, camera, rectified=True)
    output = OutputOptions(near_points=near_points, use_color=False)
    wanted = ("points2", "points2_clearing")
    messages = geometry_outputs(types, header, result_geometry(pipeline, frame, result), output, wanted, OutputState())
    return messages, camera, scene.gt


def test_too_near_pixels_cast_no_clearing_ray_and_range_limit_puts_them_at_the_nearest_depth() -> None:
    (plain, camera, gt), (limited, _, _) = artl_outputs("invalid"), artl_outputs("range_limit")
    nearest = nearest_matchable_depth(make_params("default", {"disparity_range": RANGE}), camera)
    beyond = np.isfinite(gt) & (gt >= RANGE + MARGIN)
    assert beyond.mean() > 0.2
    depth_plain = cloud_to_arrays(plain["points2"])[0][:, :, 2]
    depth_limited = cloud_to_arrays(limited["points2"])[0][:, :, 2]
    # invalid: few of them have a point; range_limit: most have one, at the nearest depth; few farther
    assert np.isfinite(depth_plain[beyond]).mean() < 0.15
    at_limit = np.isclose(depth_limited, nearest, rtol=1e-6)
    assert at_limit[beyond].mean() > 0.6
    with np.errstate(invalid="ignore"):
        assert (depth_limited[beyond] > nearest * (1 + 1e-6)).mean() < 0.15
    # range_limit changes points2 only where points2 had no point
    assert np.isnan(depth_plain[at_limit]).all()
    assert np.array_equal(depth_limited[~at_limit], depth_plain[~at_limit], equal_nan=True)
    # no clearing ray from a pixel beyond the range: each clearing point projected back to its pixel
    x, y, z = cloud_to_arrays(plain["points2_clearing"])[0].reshape(-1, 3).T
    u = np.rint(camera.fx * x / z + camera.cx_left).astype(int)
    v = np.rint(camera.fy * y / z + camera.cy).astype(int)
    assert not beyond[v, u].any()
    assert bytes(limited["points2_clearing"].data) == bytes(plain["points2_clearing"].data)


def test_diagnostics_report_the_too_near_share_and_warn_while_it_stays_high() -> None:
    diagnostics = NodeDiagnostics("/n", [])
    assert not any(diagnostics.too_near(0.02, 0.75) for _ in range(RECENT_FRAMES))
    warnings = [diagnostics.too_near(0.4, 0.75) for _ in range(RECENT_FRAMES)]
    assert not warnings[0] and "0.75 m" in warnings[-1] and "disparity_range" in warnings[-1]
    values = {kv.key: kv.value for kv in diagnostics.report(Header()).status[0].values}
    assert values["too near for disparity_range (share of pixels)"] == "0.400"
    assert values["nearest matchable depth (m)"] == "0.750"
