"""The temporal filter's odometry offline: `stereo-depth process` with left_in_base reads the bag's odometry
(a sharded run too, lead-in and all), says once where it stops or jumps and goes on, refuses a bag without it, and,
with left_in_base unset, leaves the output as it was and says once that the bag has odometry.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from odometry_bag import LEFT_IN_BASE, NS, left_in_base_matrix, left_in_base_text, write_odometry_bag

from stereo_depth.bag.reader import read_messages
from stereo_depth.cli import main
from stereo_depth.core.pose import Pose
from stereo_depth.frames.odometry import camera_in_base
from stereo_depth.messages import disparity_from_msg
from stereo_depth.options import OutputOptions

FILTER = ["--set", "temporal_filter=true", "--outputs", "disparity", "depth"]
WITH_ODOMETRY = ["--set", f"left_in_base={left_in_base_text()}"]


def disparities(bag: Path) -> list[np.ndarray]:
    return [disparity_from_msg(m) for m in read_messages(bag, [f"{NS}/disparity"])[f"{NS}/disparity"]]


def same(a: list[np.ndarray], b: list[np.ndarray]) -> bool:
    return len(a) == len(b) and all(np.array_equal(x, y, equal_nan=True) for x, y in zip(a, b, strict=True))


def test_the_rectified_camera_is_the_calibrated_one_turned_by_the_left_camera_infos_r() -> None:
    """X_rect = R X_raw: a point the calibrated camera sees at X_raw lies at left_in_base @ X_raw on the base,
    whichever frame it is given in."""
    angle = np.radians(3.0)
    r = np.array([[np.cos(angle), 0.0, np.sin(angle)], [0.0, 1.0, 0.0], [-np.sin(angle), 0.0, np.cos(angle)]])
    output = OutputOptions(left_in_base=Pose.from_list(LEFT_IN_BASE))
    raw = np.array([0.3, -0.2, 2.0, 1.0])
    rectified = np.append(r @ raw[:3], 1.0)
    on_base = left_in_base_matrix() @ raw
    np.testing.assert_allclose(camera_in_base(output, r) @ rectified, on_base, atol=1e-12)


def test_a_sharded_run_with_odometry_equals_one_pass(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    """Each shard reads the odometry of its frames and of its lead-in, so the history moves as in one pass."""
    (tmp_path / "inputs").mkdir()
    bag = tmp_path / "inputs" / "pitching"
    write_odometry_bag(bag, 60)  # 2 s: the second 1 s shard has 20 frames of lead-in before it
    assert main(["process", str(bag), str(tmp_path / "one_pass"), *FILTER, *WITH_ODOMETRY]) == 0
    assert main(["process", str(bag), str(tmp_path / "without"), *FILTER]) == 0
    one_pass = disparities(tmp_path / "one_pass")
    assert len(one_pass) == 60
    assert not same(one_pass, disparities(tmp_path / "without"))  # the odometry changes the output
    out = tmp_path / "sharded"
    args = ["--out-dir", str(out), "--jobs", "2", "--shard-seconds", "1", *FILTER, *WITH_ODOMETRY]
    assert main(["process", str(bag), *args]) == 0, capsys.readouterr().err
    assert same(disparities(out / "pitching"), one_pass)


def test_odometry_that_stops_gives_one_line_and_the_frames_keep_coming(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """The filter forgets its history once where the odometry stops, then filters without it: depth goes on."""
    bag = tmp_path / "stops"
    write_odometry_bag(bag, 30, odometry_until_s=0.4)
    assert main(["process", str(bag), str(tmp_path / "out"), *FILTER, *WITH_ODOMETRY]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if "odometry stopped" in line]
    assert len(lines) == 1 and f"{NS}/odom" in lines[0] and "(1x)" in lines[0], lines
    frames = disparities(tmp_path / "out")
    assert len(frames) == 30
    assert all(np.isfinite(d).mean() > 0.5 for d in frames[-10:])  # filtered again, not forgotten at each frame


def test_odometry_that_jumps_gives_one_line_and_the_frames_keep_coming(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """A relocalisation just after a frame: that frame and the next both see the jump; one line says so."""
    bag = tmp_path / "jumps"
    write_odometry_bag(bag, 30, jump_at_s=0.435)  # between frame 13 (0.4333 s) and the next message
    assert main(["process", str(bag), str(tmp_path / "out"), *FILTER, *WITH_ODOMETRY]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if "odom: odometry" in line]
    assert len(lines) == 1 and "odometry jumped" in lines[0] and "(1x)" in lines[0], lines
    frames = disparities(tmp_path / "out")
    assert len(frames) == 30 and all(np.isfinite(d).mean() > 0.5 for d in frames[-10:])


def test_left_in_base_without_an_odometry_topic_exits_1_naming_odom(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    bag = tmp_path / "no_odometry"
    write_odometry_bag(bag, 3, with_odometry=False)
    assert main(["process", str(bag), str(tmp_path / "out"), *FILTER, *WITH_ODOMETRY]) == 1
    errors = [line for line in capsys.readouterr().err.splitlines() if line.startswith("ERROR:")]
    assert len(errors) == 1 and f"{NS}/odom is not in the bag" in errors[0] and "--odom TOPIC" in errors[0], errors
    assert not (tmp_path / "out").exists()


def test_an_odometry_topic_without_left_in_base_gives_one_note_and_the_same_output(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    with_topic, without_topic = tmp_path / "with_topic", tmp_path / "without_topic"
    write_odometry_bag(with_topic, 8)
    write_odometry_bag(without_topic, 8, with_odometry=False)
    assert main(["process", str(with_topic), str(tmp_path / "out_with"), *FILTER]) == 0
    notes = [line for line in capsys.readouterr().out.splitlines() if "note:" in line]
    assert len(notes) == 1 and f"odometry ({NS}/odom)" in notes[0] and "left_in_base" in notes[0], notes
    assert main(["process", str(without_topic), str(tmp_path / "out_without"), *FILTER]) == 0
    assert "note:" not in capsys.readouterr().out
    assert same(disparities(tmp_path / "out_with"), disparities(tmp_path / "out_without"))
