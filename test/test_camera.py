"""Camera model: rectification of real raw pairs, depth from disparity, refusal of unusable calibrations."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from stereo_depth.core.camera import CameraInfo, StereoCamera, rectified_input
from stereo_depth.core.geometry import Rays, depth_to_points, disparity_to_depth
from stereo_depth.errors import CalibrationError
from stereo_depth.formats.euroc import stereo_camera_infos
from stereo_depth.formats.scenes import load_scene

from conftest import EUROC, SCENES, read_image


@pytest.fixture(scope="module")
def euroc_camera() -> StereoCamera:
    return StereoCamera(*stereo_camera_infos(EUROC / "cam0_sensor.yaml", EUROC / "cam1_sensor.yaml"))


def map_positions(whole: np.ndarray, fraction: np.ndarray) -> np.ndarray:
    """Source positions (x, y) in pixels from cv2.remap's fixed-point maps (CV_16SC2 + interpolation table index)."""
    step = 1.0 / cv2.INTER_TAB_SIZE
    steps = np.stack([fraction % cv2.INTER_TAB_SIZE, fraction // cv2.INTER_TAB_SIZE], -1)
    return whole.astype(np.float64) + steps * step


def euroc_pair(index: int = 0) -> tuple[np.ndarray, np.ndarray]:
    name = sorted((EUROC / "left").glob("*.png"))[index].name
    return (
        read_image(EUROC / "left" / name, cv2.IMREAD_GRAYSCALE),
        read_image(EUROC / "right" / name, cv2.IMREAD_GRAYSCALE),
    )


def row_offsets(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """|y_left - y_right| of cross-checked ORB matches: 0 for a perfectly rectified pair."""
    orb = cv2.ORB.create(2000)
    kl, dl = orb.detectAndCompute(left, None)
    kr, dr = orb.detectAndCompute(right, None)
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(dl, dr)
    return np.array([abs(kl[m.queryIdx].pt[1] - kr[m.trainIdx].pt[1]) for m in matches])


@pytest.mark.parametrize("index", [0, 3, 5])
def test_raw_euroc_pair_is_rectified_to_common_rows(euroc_camera: StereoCamera, index: int) -> None:
    left, right = euroc_pair(index)
    before = row_offsets(left, right)
    after = row_offsets(euroc_camera.rectify(left, "left"), euroc_camera.rectify(right, "right"))
    assert np.median(before) > 5.0  # measured ~12 px: the raw pair is far from rectified
    assert np.median(after) <= 1.0  # measured 0.0
    assert len(after) > 200


def test_euroc_calibration_gives_the_rig_baseline(euroc_camera: StereoCamera) -> None:
    assert euroc_camera.baseline == pytest.approx(0.1101, abs=0.0005)  # EuRoC: 110.1 mm
    assert euroc_camera.needs_rectification("left")


def test_rectification_maps_are_built_once_per_calibration(euroc_camera: StereoCamera) -> None:
    left, _ = euroc_pair()
    euroc_camera.rectify(left, "left")
    maps = euroc_camera.rectification_maps("left")
    euroc_camera.rectify(left, "left")
    assert euroc_camera.rectification_maps("left") is maps


def opencv_rectified(image: np.ndarray, info: CameraInfo) -> np.ndarray:
    """The reference: OpenCV's own float maps for K, D, R into P, built here, and cv2.remap (bilinear)."""
    size = (info.width, info.height)
    if info.distortion_model == "equidistant":
        maps = cv2.fisheye.initUndistortRectifyMap(info.k, info.d, info.r, info.p[:, :3], size, cv2.CV_32FC1)
    else:
        maps = cv2.initUndistortRectifyMap(info.k, info.d, info.r, info.p[:, :3], size, cv2.CV_32FC1)
    return cv2.remap(image, *maps, cv2.INTER_LINEAR)


def assert_close_to(ours: np.ndarray, reference: np.ndarray) -> None:
    """Our fixed-point maps (CV_16SC2, 1/32 px) against OpenCV's float maps: a grey level here and there."""
    difference = np.abs(ours.astype(np.int16) - reference.astype(np.int16))
    assert difference.mean() < 0.5  # measured 0.05
    assert np.percentile(difference, 99) <= 2  # measured 1


def grey_difference(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a.astype(np.int16) - b.astype(np.int16)).mean())


def test_rotation_is_applied_even_without_distortion(euroc_camera: StereoCamera) -> None:
    """R alone (D = 0, here the rectifying R turned 3 degrees more about the vertical) moves the image
    exactly as OpenCV's undistort+rectify maps move it, not merely "somehow"."""
    angle = np.deg2rad(3.0)
    turn = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
    left = dataclasses.replace(euroc_camera.left, d=np.zeros(5), r=turn @ euroc_camera.left.r)
    camera = StereoCamera(left, euroc_camera.right)
    image, _ = euroc_pair()
    assert camera.needs_rectification("left")
    ours = camera.rectify(image, "left")
    assert_close_to(ours, opencv_rectified(image, left))
    # the comparison tells rotations apart: without the turn, or turned the other way, it is far off
    unturned = dataclasses.replace(left, r=euroc_camera.left.r)
    backwards = dataclasses.replace(left, r=turn.T @ euroc_camera.left.r)
    assert grey_difference(ours, opencv_rectified(image, unturned)) > 10  # measured 31
    assert grey_difference(ours, opencv_rectified(image, backwards)) > 10


def test_depth_from_disparity_follows_the_middlebury_calibration() -> None:
    scene = load_scene(SCENES / "artl")
    assert scene.gt is not None
    camera = StereoCamera(*scene.camera_infos())
    depth = disparity_to_depth(scene.gt, camera)
    f, baseline_m, doffs = 935.0, 0.160, 50.0  # calib.txt: Z = baseline * f / (d + doffs)
    expected = baseline_m * f / (scene.gt + doffs)
    valid = np.isfinite(scene.gt)
    assert camera.disparity_offset == pytest.approx(-doffs)
    np.testing.assert_allclose(depth[valid], expected[valid], rtol=1e-5)
    assert np.isnan(depth[~valid]).all()


def test_points_reproject_to_their_pixels() -> None:
    scene = load_scene(SCENES / "artl")
    assert scene.gt is not None
    camera = StereoCamera(*scene.camera_infos())
    depth = disparity_to_depth(scene.gt, camera)
    points = depth_to_points(depth, Rays.for_camera(camera))
    v, u = np.nonzero(np.isfinite(depth))
    x, y, z = points[v, u, 0], points[v, u, 1], points[v, u, 2]
    np.testing.assert_allclose(camera.fx * x / z + camera.cx_left, u, atol=1e-3)
    np.testing.assert_allclose(camera.fy * y / z + camera.cy, v, atol=1e-3)
    # the Q matrix agrees with our direct formula (OpenCV's reprojection of the matched disparity)
    q_points = cv2.reprojectImageTo3D(np.nan_to_num(scene.gt, nan=-1e6).astype(np.float32), camera.q)
    np.testing.assert_allclose(q_points[v, u], points[v, u], rtol=1e-4)


def good_pair() -> tuple[CameraInfo, CameraInfo]:
    return load_scene(SCENES / "artl").camera_infos()


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda lf, r: (dataclasses.replace(lf, k=np.zeros((3, 3))), r), "uncalibrated"),
        (lambda lf, r: (lf, dataclasses.replace(r, p=np.zeros((3, 4)))), "uncalibrated"),
        (lambda lf, r: (dataclasses.replace(lf, d=np.array([np.nan, 0, 0, 0, 0])), r), "NaN"),
        (lambda lf, r: (lf, dataclasses.replace(r, width=r.width + 2)), "same resolution"),
        (lambda lf, r: (lf, dataclasses.replace(r, p=r.p * np.array([1, 1, 1, -1]))), "swapped"),
        (lambda lf, r: (dataclasses.replace(lf, distortion_model="fancy", d=np.ones(5)), r), "unknown distortion"),
    ],
    ids=["zero K", "zero P", "NaN", "size mismatch", "right on the left", "unknown model"],
)
def test_unusable_calibrations_are_refused_with_the_reason(change, message: str) -> None:  # type: ignore[no-untyped-def]
    left, right = change(*good_pair())
    with pytest.raises(CalibrationError, match=message):
        StereoCamera(left, right)


def test_zero_baseline_gives_a_camera_for_disparity_but_no_depth() -> None:
    """stereo_image_proc publishes disparity without a baseline (its own test fixtures have none): the
    pair is usable for matching; depth is refused with the reason and the fix."""
    left, right = good_pair()
    camera = StereoCamera(left, dataclasses.replace(right, p=np.hstack([right.p[:, :3], np.zeros((3, 1))])))
    assert camera.baseline == 0 and camera.no_depth_reason is not None
    assert "disparity is published" in camera.no_depth_reason and "baseline parameter" in camera.no_depth_reason
    with pytest.raises(CalibrationError, match="baseline 0 m"):
        disparity_to_depth(np.full((camera.height, camera.width), 10.0, np.float32), camera)
    assert StereoCamera(*good_pair()).no_depth_reason is None


def test_rectified_input_needs_only_p() -> None:
    """A rectified image's camera_info with only P (K = 0, D and R empty), as stereo_image_proc's test
    fixtures publish: the camera is P's, and no remapping is done."""
    left, right = good_pair()
    bare_left, bare_right = (
        CameraInfo.from_values(info.width, info.height, np.zeros(9), [], np.zeros(9), info.p, "")
        for info in (left, right)
    )
    with pytest.raises(CalibrationError, match="K has no focal length"):
        StereoCamera(bare_left, bare_right)
    camera = StereoCamera(rectified_input(bare_left), rectified_input(bare_right))
    assert (camera.fx, camera.baseline) == (StereoCamera(left, right).fx, StereoCamera(left, right).baseline)
    assert not camera.needs_rectification("left") and not camera.needs_rectification("right")
    assert rectified_input(left) is left  # a full camera_info keeps its K, D and R


def test_image_of_another_size_than_its_calibration_is_refused(euroc_camera: StereoCamera) -> None:
    left, _ = euroc_pair()
    with pytest.raises(CalibrationError, match="752x480"):
        euroc_camera.rectify(left[:200], "left")


def test_rational_polynomial_with_plumb_bob_terms_rectifies_like_plumb_bob(euroc_camera: StereoCamera) -> None:
    left = dataclasses.replace(
        euroc_camera.left, distortion_model="rational_polynomial", d=np.concatenate([euroc_camera.left.d, np.zeros(3)])
    )
    camera = StereoCamera(left, euroc_camera.right)
    got = map_positions(*camera.rectification_maps("left"))
    expected = map_positions(*euroc_camera.rectification_maps("left"))
    # two OpenCV distortion paths round differently: at most one step of the fixed-point map apart
    np.testing.assert_allclose(got, expected, rtol=0, atol=1 / cv2.INTER_TAB_SIZE + 1e-9)


def test_equidistant_model_rectifies_like_opencv_fisheye(euroc_camera: StereoCamera) -> None:
    """equidistant D goes through cv2.fisheye's model (with the rectifying R), not the pinhole one."""
    d = np.array([-0.03, 0.01, -0.005, 0.001])
    left = dataclasses.replace(euroc_camera.left, distortion_model="equidistant", d=d)
    camera = StereoCamera(left, euroc_camera.right)
    image, _ = euroc_pair()
    ours = camera.rectify(image, "left")
    assert_close_to(ours, opencv_rectified(image, left))
    pinhole = dataclasses.replace(left, distortion_model="plumb_bob", d=np.append(d, 0.0))
    assert grey_difference(ours, opencv_rectified(image, pinhole)) > 10  # measured 31: another model
    # with R = I, cv2.fisheye.undistortImage is the same operation
    unrotated = dataclasses.replace(left, r=np.eye(3))
    size = (left.width, left.height)
    reference = cv2.fisheye.undistortImage(image, left.k, d, Knew=left.p[:, :3], new_size=size)
    assert_close_to(StereoCamera(unrotated, euroc_camera.right).rectify(image, "left"), reference)
