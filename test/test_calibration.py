"""Stereo calibration from the OpenCV sample chessboard pairs, and the camera_info YAML files it writes."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from stereo_depth.core.calibration import (
    Board,
    ImagePair,
    StereoCalibration,
    Views,
    calibrate_stereo,
    detect_views,
    find_corners,
    make_report,
    rectified_row_errors,
)
from stereo_depth.core.camera import StereoCamera
from stereo_depth.errors import CalibrationError
from stereo_depth.formats.camera_info_yaml import camera_info_to_yaml, parse_camera_info_yaml, read_camera_info_yaml

from conftest import DATA

CHESSBOARD = DATA / "chessboard"
BOARD = Board(9, 6, 0.025)  # 9x6 inner corners; the sample's square size is unpublished, 25 mm assumed


def read_grey(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    assert image is not None, path
    return np.asarray(image)


def chessboard_pairs() -> list[ImagePair]:
    lefts = sorted(CHESSBOARD.glob("left*.jpg"))
    return [ImagePair(p.name, read_grey(p), read_grey(CHESSBOARD / p.name.replace("left", "right"))) for p in lefts]


@pytest.fixture(scope="module")
def views() -> Views:
    return detect_views(chessboard_pairs(), BOARD)


@pytest.fixture(scope="module")
def calibration(views: Views) -> StereoCalibration:
    return calibrate_stereo(views, BOARD)


def test_every_sample_pair_shows_the_board_on_both_sides(views: Views) -> None:
    assert len(views) == 10
    assert views.rejected == []


def test_reprojection_errors_are_subpixel(calibration: StereoCalibration) -> None:
    # measured with OpenCV 5.0: left 0.427, right 0.483, stereo 0.472 px
    assert calibration.rms_left < 0.6
    assert calibration.rms_right < 0.6
    assert calibration.rms_stereo < 0.6


def test_corners_share_rows_after_rectification(views: Views, calibration: StereoCalibration) -> None:
    rows = np.abs(rectified_row_errors(StereoCamera(calibration.left, calibration.right), views))
    assert np.median(rows) < 0.5  # measured 0.108 px


def test_baseline_is_in_board_units(calibration: StereoCalibration) -> None:
    """OpenCV's stereo_calib finds T ~ 3.35 squares for these pairs; with 25 mm squares that is ~84 mm."""
    camera = StereoCamera(calibration.left, calibration.right)
    assert camera.baseline == pytest.approx(3.35 * BOARD.square, rel=0.03)
    assert calibration.translation[0] < 0  # right camera on the right: points move to -x in it


def test_report_states_coverage_and_errors(views: Views, calibration: StereoCalibration) -> None:
    report = make_report(views, calibration)
    assert 0.3 < report.coverage_left < 0.6  # measured 43%: the sample boards stay near the centre
    assert 0.3 < report.coverage_right < 0.6
    assert report.row_error_median <= report.row_error_p95
    text = report.text()
    assert "stereo 0.47" in text
    assert "coverage" in text


def test_corners_start_at_the_top_whatever_way_the_board_is_held() -> None:
    """Left and right must list the corners in the same order, or stereoCalibrate pairs wrong corners."""
    grey = read_grey(CHESSBOARD / "left01.jpg")
    for image in (grey, cv2.rotate(grey, cv2.ROTATE_180)):
        corners = find_corners(image, BOARD)
        assert corners is not None
        assert corners.shape == (54, 1, 2)
        assert corners[0, 0, 1] < corners[-1, 0, 1]


def test_too_few_views_are_refused(views: Views) -> None:
    few = Views(views.size, views.names[:3], views.left[:3], views.right[:3])
    with pytest.raises(CalibrationError, match=r"only 3 of 3 pairs .* need at least 6"):
        calibrate_stereo(few, BOARD)


def test_pairs_of_different_sizes_are_refused() -> None:
    pair = chessboard_pairs()[0]
    small = ImagePair("01", pair.left, cv2.resize(pair.right, (320, 240)))
    with pytest.raises(CalibrationError, match="left image is 640x480 but right is 320x240"):
        detect_views([small], BOARD)


def test_board_size_counts_inner_corners() -> None:
    with pytest.raises(CalibrationError, match="inner corners"):
        Board(1, 6, 0.025)
    with pytest.raises(CalibrationError, match="must be positive"):
        Board(9, 6, 0.0)


# ---------------------------------------------------------------- camera_info YAML


def test_yaml_round_trip_gives_the_same_rectification(calibration: StereoCalibration, tmp_path: Path) -> None:
    (tmp_path / "left.yaml").write_text(camera_info_to_yaml(calibration.left, "left"))
    (tmp_path / "right.yaml").write_text(camera_info_to_yaml(calibration.right, "right"))
    left, right = read_camera_info_yaml(tmp_path / "left.yaml"), read_camera_info_yaml(tmp_path / "right.yaml")
    assert left == calibration.left
    assert right == calibration.right
    written, loaded = StereoCamera(calibration.left, calibration.right), StereoCamera(left, right)
    for side in ("left", "right"):
        for a, b in zip(written.rectification_maps(side), loaded.rectification_maps(side), strict=True):
            assert np.array_equal(a, b)


def test_yaml_has_the_camera_calibration_parsers_layout(calibration: StereoCalibration) -> None:
    text = camera_info_to_yaml(calibration.right, "right")
    doc = yaml.safe_load(text)
    assert list(doc) == [
        "image_width",
        "image_height",
        "camera_name",
        "camera_matrix",
        "distortion_model",
        "distortion_coefficients",
        "rectification_matrix",
        "projection_matrix",
    ]
    assert (doc["image_width"], doc["image_height"], doc["camera_name"]) == (640, 480, "right")
    assert doc["distortion_model"] == "plumb_bob"
    for key, rows, cols in (
        ("camera_matrix", 3, 3),
        ("distortion_coefficients", 1, 5),
        ("rectification_matrix", 3, 3),
        ("projection_matrix", 3, 4),
    ):
        assert (doc[key]["rows"], doc[key]["cols"], len(doc[key]["data"])) == (rows, cols, rows * cols)
    assert "  data: [" in text  # flow-style lists, as the C++ emitter writes them


def test_a_file_written_by_ros_tools_loads() -> None:
    """camera_calibration_parsers' own output: integers for zeros, no distortion_model (plumb_bob then)."""
    text = """image_width: 800
image_height: 600
camera_name: 00b09d0100990bb6
camera_matrix:
  rows: 3
  cols: 3
  data: [538.63, 0, 457.698, 0, 539.723, 297.003, 0, 0, 1]
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.30678, 0.0825017, 0.0028784, -0.00015829, 0]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [538.63, 0, 457.698, 0, 0, 539.723, 297.003, 0, 0, 0, 1, 0]
"""
    info = parse_camera_info_yaml(text)
    assert (info.width, info.height, info.distortion_model) == (800, 600, "plumb_bob")
    assert info.k[0, 0] == 538.63
    assert info.p.shape == (3, 4)


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda d: d.pop("projection_matrix"), "'projection_matrix' is missing"),
        (lambda d: d["camera_matrix"].update(rows=2), "'camera_matrix' is 2x3 with 9 values; expected 3x3"),
        (lambda d: d.pop("image_width"), "no image_width"),
    ],
)
def test_broken_yaml_names_the_problem(calibration: StereoCalibration, edit: object, match: str) -> None:
    doc = yaml.safe_load(camera_info_to_yaml(calibration.left, "left"))
    edit(doc)  # type: ignore[operator]
    with pytest.raises(CalibrationError, match=match):
        parse_camera_info_yaml(yaml.safe_dump(doc), "left.yaml")
