"""`stereo-depth process` on recordings as drivers and users really make them: a rosbag2 folder named
`x.bag`, a right camera_info without baseline, topics swapped. `--set baseline=` and
`--set swap_left_right=` state what the driver got wrong, as the nodes' parameters of the same names do."""

from __future__ import annotations

import dataclasses
import shutil
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from stereo_depth.bag.make import StreamLayout, write_stream
from stereo_depth.bag.reader import read_messages
from stereo_depth.bag.recording import open_reader
from stereo_depth.bag.sources import SourceFrame, read_frames
from stereo_depth.bag.writer import BagWriter
from stereo_depth.cli import main
from stereo_depth.core.camera import StereoCamera
from stereo_depth.messages import disparity_from_msg, image_to_array

from conftest import SCENES

MIDDLEBURY_BAG = Path(__file__).resolve().parents[1] / "bags" / "middlebury"
NS = "/stereo"
FRAMES = [SCENES / "artl"] * 2


def frames(change: str = "") -> Iterator[SourceFrame]:
    """The scene as a driver publishes it: unchanged, with the right P[0,3] zero, or left and right swapped."""
    for frame in read_frames(FRAMES):
        if change == "no baseline":
            p = frame.right_info.p.copy()
            p[0, 3] = 0.0
            frame = dataclasses.replace(frame, right_info=dataclasses.replace(frame.right_info, p=p))
        elif change == "swapped":
            frame = dataclasses.replace(
                frame, left=frame.right, right=frame.left, left_info=frame.right_info, right_info=frame.left_info
            )
        yield frame


def recording(folder: Path, change: str = "") -> Path:
    bag = folder / (change.replace(" ", "_") or "as_calibrated")
    if bag.exists():  # written by an earlier test of this module
        return bag
    with BagWriter(bag) as writer:
        write_stream(frames(change), writer, StreamLayout())
    return bag


def process(capsys: pytest.CaptureFixture[str], in_bag: Path, out: Path, *extra: str) -> tuple[int, str, str]:
    code = main(["process", str(in_bag), str(out), *extra])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def outputs(bag: Path) -> dict[str, list[np.ndarray]]:
    """What came out, per output: disparity and depth pixels, points2 counted."""
    reader = open_reader(bag)
    present = {c.topic for c in reader.connections}
    reader.close()
    topics = [f"{NS}/{name}" for name in ("disparity", "depth", "points2") if f"{NS}/{name}" in present]
    messages = read_messages(bag, topics)
    read = {"disparity": disparity_from_msg, "depth": image_to_array, "points2": lambda _: np.zeros(0)}
    return {name: [np.array(read(m)) for m in messages.get(f"{NS}/{name}", [])] for name, read in read.items()}


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("driver_fixes")


@pytest.fixture(scope="module")
def reference(folder: Path) -> dict[str, list[np.ndarray]]:
    out = folder / "reference_out"
    assert main(["process", str(recording(folder)), str(out)]) == 0
    return outputs(out)


def test_rosbag2_folder_named_like_a_ros1_bag_is_processed(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    """`ros2 bag record -o run.bag` makes a folder `run.bag/`: it is a rosbag2 by its metadata.yaml."""
    bag = tmp_path / "x.bag"
    shutil.copytree(MIDDLEBURY_BAG, bag)
    code, out, err = process(capsys, bag, tmp_path / "out")
    assert code == 0, err
    assert "frames out: 3" in out
    assert len(outputs(tmp_path / "out")["disparity"]) == 3


def test_what_is_not_a_bag_is_named_as_such(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    (tmp_path / "notes.bag").write_text("not a recording\n")
    code, _, err = process(capsys, tmp_path / "notes.bag", tmp_path / "out")
    assert code == 1 and "is a file but not a ROS 1 bag" in err
    (tmp_path / "folder.bag").mkdir()
    code, _, err = process(capsys, tmp_path / "folder.bag", tmp_path / "out")
    assert code == 1 and "without metadata.yaml, so not a rosbag2" in err
    assert not (tmp_path / "out").exists()


def test_no_baseline_gives_disparity_and_one_warning(
    capsys: pytest.CaptureFixture[str], folder: Path, reference: dict[str, list[np.ndarray]]
) -> None:
    """As stereo_image_proc: the disparity is the calibrated one; depth and points2 are left out, said once."""
    out = folder / "no_baseline_out"
    code, printed, err = process(capsys, recording(folder, "no baseline"), out)
    assert code == 0, err
    assert printed.count("gives baseline 0 m") == 1 and "set the baseline parameter" in printed
    found = outputs(out)
    assert (len(found["disparity"]), found["depth"], found["points2"]) == (2, [], [])
    for ours, expected in zip(found["disparity"], reference["disparity"], strict=True):
        np.testing.assert_array_equal(ours, expected)


def test_baseline_set_by_the_user_gives_the_calibrated_depth(
    capsys: pytest.CaptureFixture[str], folder: Path, reference: dict[str, list[np.ndarray]]
) -> None:
    frame = next(read_frames(FRAMES))
    baseline = StereoCamera(frame.left_info, frame.right_info).baseline
    out = folder / "baseline_set_out"
    code, _, err = process(capsys, recording(folder, "no baseline"), out, "--set", f"baseline={baseline!r}")
    assert code == 0, err
    assert f"inputs corrected: baseline {baseline!r} m" in err
    found = outputs(out)
    assert len(found["points2"]) == 2
    for ours, expected in zip(found["depth"], reference["depth"], strict=True):
        np.testing.assert_allclose(ours, expected, rtol=1e-6)


def test_swapped_topics_are_said_and_undone_by_swap_left_right(
    capsys: pytest.CaptureFixture[str], folder: Path, reference: dict[str, list[np.ndarray]]
) -> None:
    bag = recording(folder, "swapped")
    code, printed, err = process(capsys, bag, folder / "swapped_out")
    assert code == 0, err
    assert "left and right look swapped, set swap_left_right" in printed
    out = folder / "unswapped_out"
    code, _, err = process(capsys, bag, out, "--set", "swap_left_right=true")
    assert code == 0, err
    assert "inputs corrected: swap_left_right" in err
    found = outputs(out)
    for name in ("disparity", "depth"):
        for ours, expected in zip(found[name], reference[name], strict=True):
            np.testing.assert_array_equal(ours, expected)
