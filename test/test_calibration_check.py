"""The calibration check on real EuRoC frames: true calibration OK, a rotated one WARN/ERROR."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from test_calibration import read_grey

from stereo_depth.core.calibration_check import Level, check_rectified_pair
from stereo_depth.core.camera import CameraInfo, StereoCamera
from stereo_depth.formats.euroc import stereo_camera_infos

from conftest import EUROC

FRAMES = sorted((EUROC / "left").glob("*.png"))


def rotated_about_baseline(info: CameraInfo, degrees: float) -> CameraInfo:
    """The right camera's rectification turned about the x axis: what a knock to the rig does."""
    angle = np.radians(degrees)
    c, s = np.cos(angle), np.sin(angle)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    return CameraInfo.from_values(info.width, info.height, info.k, info.d, rx @ info.r, info.p, info.distortion_model)


def rectified_pairs(degrees: float) -> list[tuple[np.ndarray, np.ndarray]]:
    left, right = stereo_camera_infos(EUROC / "cam0_sensor.yaml", EUROC / "cam1_sensor.yaml")
    camera = StereoCamera(left, rotated_about_baseline(right, degrees))
    return [
        (camera.rectify(read_grey(path), "left"), camera.rectify(read_grey(EUROC / "right" / path.name), "right"))
        for path in FRAMES
    ]


def test_true_calibration_is_ok() -> None:
    for left, right in rectified_pairs(0.0):
        check = check_rectified_pair(left, right)
        assert check.level == Level.OK, check.message
        assert check.median_dy < 0.3  # measured 0.14-0.16 px
        assert check.inliers >= 100  # measured 220-255


def test_half_a_degree_about_the_baseline_is_an_error() -> None:
    """0.5 deg at f = 436 px moves rows by f*tan(0.5 deg) = 3.8 px; measured 3.90-3.95 px."""
    for left, right in rectified_pairs(0.5):
        check = check_rectified_pair(left, right)
        assert check.level == Level.ERROR, check.message  # above 1.5 px (README)
        assert check.median_dy == pytest.approx(3.8, abs=0.4)
        assert "recalibrate" in check.message


def test_a_tenth_of_a_degree_is_a_warning() -> None:
    """0.1 deg = 0.76 px expected, 0.79-0.83 px measured: inside the WARN band (0.5 to 1.5 px)."""
    for left, right in rectified_pairs(0.1)[:2]:
        check = check_rectified_pair(left, right)
        assert check.level == Level.WARN, check.message


def test_colour_input_gives_the_grey_result() -> None:
    left, right = rectified_pairs(0.0)[0]
    colour = check_rectified_pair(cv2.cvtColor(left, cv2.COLOR_GRAY2BGR), cv2.cvtColor(right, cv2.COLOR_GRAY2BGR))
    assert colour == check_rectified_pair(left, right)


def test_a_blank_view_cannot_be_judged() -> None:
    """No texture is no evidence: STALE, not an alarm that would send people recalibrating."""
    blank = np.full((480, 752), 128, np.uint8)
    check = check_rectified_pair(blank, blank)
    assert check.level == Level.STALE
    assert check.inliers == 0
    assert np.isnan(check.median_dy)
