"""`stereo-depth calibrate` and `stereo-depth check-calibration` end to end, good input and bad."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from test_calibration import chessboard_pairs, read_grey
from test_calibration_check import rotated_about_baseline

from stereo_depth.bag.make import StreamLayout, write_stream
from stereo_depth.bag.sources import SourceFrame
from stereo_depth.bag.writer import BagWriter
from stereo_depth.cli import main
from stereo_depth.core.camera import CameraInfo, StereoCamera
from stereo_depth.formats.camera_info_yaml import camera_info_to_yaml, read_camera_info_yaml
from stereo_depth.formats.euroc import stereo_camera_infos

from conftest import DATA, EUROC

CHESSBOARD = DATA / "chessboard"
CALIBRATE = ["--board", "9x6", "--square", "0.025"]


def run_cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


def copy_pairs(target: Path, numbers: list[str]) -> Path:
    target.mkdir()
    for number in numbers:
        for side in ("left", "right"):
            shutil.copy(CHESSBOARD / f"{side}{number}.jpg", target)
    return target


def test_calibrate_writes_camera_info_report_and_picture(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "calib"
    code, stdout, _ = run_cli(["calibrate", str(CHESSBOARD), *CALIBRATE, "--out", str(out)], capsys)
    assert code == 0
    assert sorted(p.name for p in out.iterdir()) == ["left.yaml", "rectified.png", "report.txt", "right.yaml"]
    report = (out / "report.txt").read_text()
    assert "views used: 10, rejected: 0" in report
    assert "stereo 0.47" in report
    assert report in stdout
    camera = StereoCamera(read_camera_info_yaml(out / "left.yaml"), read_camera_info_yaml(out / "right.yaml"))
    assert camera.baseline == pytest.approx(0.084, abs=0.002)
    picture = cv2.imread(str(out / "rectified.png"))
    assert picture is not None
    assert picture.shape == (480, 1280, 3)
    assert not list(tmp_path.glob(".calib.*"))  # no temporary folder left behind


def test_calibrate_reads_left_and_right_subfolders(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    source = tmp_path / "pairs"
    for side in ("left", "right"):
        (source / side).mkdir(parents=True)
        for path in CHESSBOARD.glob(f"{side}*.jpg"):
            shutil.copy(path, source / side / path.name.replace(side, "view"))
    code, _, _ = run_cli(["calibrate", str(source), *CALIBRATE, "--out", str(tmp_path / "out")], capsys)
    assert code == 0
    assert (tmp_path / "out" / "right.yaml").is_file()


@pytest.mark.parametrize(
    ("name", "storage", "layout"),
    [
        ("board_bag", "mcap", StreamLayout(rate_hz=10.0)),
        # as a camera being calibrated is often recorded: ROS 1, JPEG, no camera_info yet
        ("board.bag", "rosbag1", StreamLayout(rate_hz=10.0, compress_images="jpeg", camera_info=False)),
    ],
    ids=["rosbag2", "ros1_jpeg_without_camera_info"],
)
def test_calibrate_reads_a_bag(
    name: str, storage: str, layout: StreamLayout, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    unknown = CameraInfo.from_values(640, 480, np.zeros(9), np.zeros(5), np.eye(3), np.zeros(12))
    frames = [SourceFrame(p.name, p.left, p.right, unknown, unknown, None) for p in chessboard_pairs()]
    with BagWriter(tmp_path / name, storage=storage) as writer:
        write_stream(frames, writer, layout)
    out = tmp_path / "out"
    code, stdout, _ = run_cli(["calibrate", str(tmp_path / name), *CALIBRATE, "--out", str(out)], capsys)
    assert code == 0
    assert "views used: 10" in stdout
    assert read_camera_info_yaml(out / "left.yaml").width == 640


def assert_refused(argv: list[str], out: Path, match: str, capsys: pytest.CaptureFixture[str]) -> None:
    code, stdout, stderr = run_cli(argv, capsys)
    assert code == 1
    lines = stderr.strip().splitlines()
    assert len(lines) == 1
    assert lines[0].startswith("ERROR: ")
    assert match in lines[0]
    assert not out.exists()
    assert not list(out.parent.glob(f".{out.name}.*"))
    assert stdout == ""


def test_a_folder_without_a_board_writes_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    source = tmp_path / "no_board"
    source.mkdir()
    for i, path in enumerate(sorted((EUROC / "left").glob("*.png"))):
        shutil.copy(path, source / f"left{i:02d}.png")
        shutil.copy(EUROC / "right" / path.name, source / f"right{i:02d}.png")
    out = tmp_path / "out"
    argv = ["calibrate", str(source), *CALIBRATE, "--out", str(out)]
    assert_refused(argv, out, "no pair shows the whole 9x6 board on both sides (6 pairs tried)", capsys)


def test_pairs_of_different_sizes_write_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    source = copy_pairs(tmp_path / "mixed", ["01", "02", "03", "05", "06", "07"])
    small = cv2.resize(read_grey(source / "right03.jpg"), (320, 240))
    cv2.imwrite(str(source / "right03.jpg"), small)
    out = tmp_path / "out"
    argv = ["calibrate", str(source), *CALIBRATE, "--out", str(out)]
    assert_refused(argv, out, "left image is 640x480 but right is 320x240", capsys)


def test_too_few_views_write_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    source = copy_pairs(tmp_path / "few", ["01", "02", "03"])
    out = tmp_path / "out"
    argv = ["calibrate", str(source), *CALIBRATE, "--out", str(out)]
    assert_refused(argv, out, "only 3 of 3 pairs show the board on both sides; need at least 6", capsys)


def test_an_image_without_its_partner_writes_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    source = copy_pairs(tmp_path / "odd", ["01", "02", "03", "05", "06", "07"])
    (source / "right07.jpg").unlink()
    out = tmp_path / "out"
    assert_refused(["calibrate", str(source), *CALIBRATE, "--out", str(out)], out, "no partner for left07.jpg", capsys)


def test_a_bad_board_spec_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    argv = ["calibrate", str(CHESSBOARD), "--board", "9by6", "--square", "0.025", "--out", str(out)]
    assert_refused(argv, out, "--board expects COLSxROWS", capsys)


# ---------------------------------------------------------------- check-calibration


@pytest.fixture(scope="module")
def euroc_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("bags") / "euroc"
    assert main(["make-bag", str(EUROC), str(path)]) == 0
    return path


def test_check_calibration_says_ok_with_the_true_calibration(
    euroc_bag: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, stdout, _ = run_cli(["check-calibration", str(euroc_bag)], capsys)
    assert code == 0
    lines = stdout.strip().splitlines()
    assert len(lines) == 1 + 6 + 1  # header, one line per frame, verdict
    assert all(line.endswith("OK") for line in lines[1:7])
    assert lines[-1].startswith("verdict: OK: 6 of 6 frames judged")


def write_rotated_calibration(folder: Path, degrees: float) -> None:
    """The true EuRoC calibration as left.yaml / right.yaml, the right camera turned about the baseline."""
    left, right = stereo_camera_infos(EUROC / "cam0_sensor.yaml", EUROC / "cam1_sensor.yaml")
    (folder / "left.yaml").write_text(camera_info_to_yaml(left, "left"))
    (folder / "right.yaml").write_text(camera_info_to_yaml(rotated_about_baseline(right, degrees), "right"))


def test_check_calibration_says_error_with_a_rotated_calibration(
    euroc_bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    write_rotated_calibration(tmp_path, 0.5)
    code, stdout, _ = run_cli(["check-calibration", str(euroc_bag), "--camera-info", str(tmp_path)], capsys)
    assert code == 2
    assert stdout.strip().splitlines()[-1].startswith("verdict: ERROR")
    assert "recalibrate" in stdout


def test_check_calibration_says_warn_with_a_slightly_rotated_calibration(
    euroc_bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """0.12 degrees about the baseline puts the rows ~1 px apart (measured 0.98): WARN, exit status 1."""
    write_rotated_calibration(tmp_path, 0.12)
    code, stdout, stderr = run_cli(["check-calibration", str(euroc_bag), "--camera-info", str(tmp_path)], capsys)
    assert code == 1 and "ERROR:" not in stderr
    lines = stdout.strip().splitlines()
    assert all(line.endswith("WARN") for line in lines[1:7])
    assert lines[-1].startswith("verdict: WARN: 6 of 6 frames judged")


def test_check_calibration_refuses_a_calibration_of_another_camera_mode(
    euroc_bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Its frames are decoded as the nodes decode them (frames.decode_frame): a calibration of another
    image size is refused with the inputs named, the bag's images and the calibration files."""
    infos = stereo_camera_infos(EUROC / "cam0_sensor.yaml", EUROC / "cam1_sensor.yaml")
    for side, info in zip(("left", "right"), infos, strict=True):
        other_mode = dataclasses.replace(info, width=376, height=240)
        (tmp_path / f"{side}.yaml").write_text(camera_info_to_yaml(other_mode, side))
    code, stdout, stderr = run_cli(["check-calibration", str(euroc_bag), "--camera-info", str(tmp_path)], capsys)
    assert code == 1 and "verdict" not in stdout
    assert stderr.startswith("ERROR: ") and stderr.count("\n") == 1
    assert "are 752x480 but left --camera-info and right --camera-info say 376x240" in stderr


def test_a_second_calibration_replaces_the_first_as_a_whole(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "calib"
    assert run_cli(["calibrate", str(CHESSBOARD), *CALIBRATE, "--out", str(out)], capsys)[0] == 0
    first = (out / "left.yaml").read_text()
    few = copy_pairs(tmp_path / "six", ["01", "02", "03", "05", "06", "07"])
    assert run_cli(["calibrate", str(few), *CALIBRATE, "--out", str(out)], capsys)[0] == 0
    assert (out / "left.yaml").read_text() != first  # six views calibrate a little differently
    assert "views used: 6" in (out / "report.txt").read_text()  # every file is the second run's
    assert sorted(p.name for p in tmp_path.iterdir()) == ["calib", "six"]  # nothing left beside it


def test_an_output_folder_with_other_files_is_refused_untouched(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "config"
    out.mkdir()
    (out / "robot.yaml").write_text("mine")
    code, _, err = run_cli(["calibrate", str(CHESSBOARD), *CALIBRATE, "--out", str(out)], capsys)
    assert code == 1 and err.count("ERROR:") == 1 and "holds other files (robot.yaml)" in err
    assert [p.name for p in out.iterdir()] == ["robot.yaml"]
